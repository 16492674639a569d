//! The terrain curriculum (IsaacLab's terrain levels): which column an environment walks next, how
//! high its steps are, and when it moves up or down a level.
use g1_sim::world::{Outdoor, TerrainKind, TerrainSpec, World};
use labkit::rng::Rng;

/// Curriculum levels: step height `0.05 + 0.021·level` m, 0.05 … 0.26 m.
pub const LEVELS: usize = 11;

/// Most steps a curriculum staircase has.
pub const MAX_STEPS: usize = 8;

/// Step height of a level, m.
pub fn level_height(level: usize) -> f64 {
    0.05 + 0.021 * level as f64
}

/// Flat ground's default share of environments (IsaacLab's rough terrain keeps a flat column too).
pub const FLAT_SHARE: f64 = 0.15;

/// The default share of stair environments that climb (the columns up and outdoor up).
pub const UP_SHARE: f64 = 0.5;

/// How the environments split between the columns: flat ground's share of all of them, and the
/// climbing columns' share of the stair ones. The stair columns otherwise keep the table's ratios
/// (indoor 0.3 : outdoor 0.125 on each side).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ColumnMix {
    pub flat: f64,
    pub up: f64,
}

impl Default for ColumnMix {
    fn default() -> Self {
        Self {
            flat: FLAT_SHARE,
            up: UP_SHARE,
        }
    }
}

/// Terrain columns of the curriculum (IsaacLab's sub-terrain types).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize, serde::Deserialize)]
pub enum Column {
    Flat,
    Up,
    Down,
    OutdoorUp,
    OutdoorDown,
}

impl Column {
    /// Share of environments per column by default ([`FLAT_SHARE`] on flat ground).
    const MIX: [(Column, f64); 5] = [
        (Column::Flat, FLAT_SHARE),
        (Column::Up, 0.3),
        (Column::Down, 0.3),
        (Column::OutdoorUp, 0.125),
        (Column::OutdoorDown, 0.125),
    ];

    /// The column environment `i` of `n` keeps for the whole run, in the mix's shares (IsaacLab's
    /// terrain types: an environment moves up and down the levels of its own column). Drawing a
    /// column per episode while the level was the environment's let the columns' difficulties
    /// mix: successes going down promoted an environment that then failed every staircase up at
    /// that height (run 13, in the training environment: down 15.5 cm 5/8, up 11 and 15.5 cm 0/8).
    pub fn for_env(i: usize, n: usize, only: Option<Column>, mix: ColumnMix) -> Column {
        if let Some(c) = only {
            return c;
        }
        Self::at_share((i as f64 + 0.5) / n.max(1) as f64, mix)
    }

    /// Whether the column's staircases go up (indoor or outdoor).
    pub fn climbs(self) -> bool {
        matches!(self, Column::Up | Column::OutdoorUp)
    }

    pub fn draw(rng: &mut Rng, only: Option<Column>, mix: ColumnMix) -> Column {
        if let Some(c) = only {
            return c;
        }
        Self::at_share(rng.uniform(), mix)
    }

    /// Each column's share of environments under `mix`.
    pub fn mix(mix: ColumnMix) -> [(Column, f64); 5] {
        // At the defaults every scale is exactly 1, so default runs keep their columns bit for bit.
        let stairs = (1.0 - mix.flat) / (1.0 - FLAT_SHARE);
        let up = mix.up / UP_SHARE;
        let down = (1.0 - mix.up) / (1.0 - UP_SHARE);
        Self::MIX.map(|(c, p)| {
            let share = match c {
                Column::Flat => mix.flat,
                Column::Up | Column::OutdoorUp => p * stairs * up,
                Column::Down | Column::OutdoorDown => p * stairs * down,
            };
            (c, share)
        })
    }

    /// The column at `u` ∈ [0, 1) along the mix's cumulative shares.
    fn at_share(mut u: f64, mix: ColumnMix) -> Column {
        for (c, p) in Self::mix(mix) {
            if u < p {
                return c;
            }
            u -= p;
        }
        Column::Flat
    }
}

/// The level after an episode on stairs: up after a success (past the top, a random level, so the
/// whole range stays in the mix), down when the robot did not get halfway to the last riser; never
/// below `floor` (the lowest level this environment's column may train at).
pub fn next_level(level: usize, success: bool, walked_half: bool, floor: usize, rng: &mut Rng) -> usize {
    let floor = floor.min(LEVELS - 1);
    let next = if success {
        if level + 1 >= LEVELS {
            rng.int(floor as u64, LEVELS as u64 - 1) as usize
        } else {
            level + 1
        }
    } else if !walked_half {
        level.saturating_sub(1)
    } else {
        level
    };
    next.max(floor)
}

/// The level an episode's staircase is drawn at: the environment's curriculum `level`, or, for a
/// review episode, a level drawn uniformly from `floor` to `level`. Reviews keep the heights an
/// environment has already passed in the mix: a column that trains only at its frontier forgets
/// them (runs 28–30 lost the 12–14 cm descents while their descending columns sat at 21 cm).
pub fn episode_level(level: usize, floor: usize, review: bool, rng: &mut Rng) -> usize {
    let level = level.min(LEVELS - 1);
    let floor = floor.min(level);
    if review {
        rng.int(floor as u64, level as u64) as usize
    } else {
        level
    }
}

/// Draws the next world of `column` at `level`.
pub fn draw_world(column: Column, level: usize, r: &mut Rng) -> World {
    let (kind, outdoor) = match column {
        Column::Flat => return World::preset("flat").expect("preset"),
        Column::Up => (TerrainKind::StairsUp, false),
        Column::Down => (TerrainKind::StairsDown, false),
        Column::OutdoorUp => (TerrainKind::StairsUp, true),
        Column::OutdoorDown => (TerrainKind::StairsDown, true),
    };
    let start_distance = r.range(0.6, 2.0);
    let width = r.range(1.2, 2.5);
    let spec = TerrainSpec {
        kind,
        step_height: (level_height(level) + r.range(-0.01, 0.01)).clamp(0.04, 0.27),
        step_depth: r.range(0.22, 0.40),
        steps: r.int(3, MAX_STEPS as u64) as usize,
        width,
        yaw_deg: r.range(-30.0, 30.0),
        start_distance,
        lateral_offset: r.range(-0.15, 0.15) * width,
        landing_before: start_distance + r.range(1.0, 2.0),
        landing_after: r.range(1.5, 3.0),
        outdoor: outdoor.then(|| Outdoor {
            height_jitter: 0.1,
            depth_jitter: 0.1,
            tread_slope_deg: r.range(0.0, 3.0),
            nosing_radius: r.range(0.0, 0.03),
            seed: r.next_u64(),
        }),
    };
    World::build("train", spec).unwrap_or_else(|_| World::preset("flat").expect("preset"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_never_fall_below_the_floor_and_the_top_redraws_above_it() {
        let mut rng = Rng(7);
        // Without a floor: a failure short of halfway demotes, down to 0.
        assert_eq!(next_level(3, false, false, 0, &mut rng), 2);
        assert_eq!(next_level(0, false, false, 0, &mut rng), 0);
        assert_eq!(next_level(3, true, true, 0, &mut rng), 4);
        assert_eq!(next_level(3, false, true, 0, &mut rng), 3);
        // With a floor of 4: no demotion below it, a level under it is raised to it.
        assert_eq!(next_level(4, false, false, 4, &mut rng), 4);
        assert_eq!(next_level(5, false, false, 4, &mut rng), 4);
        assert_eq!(next_level(1, false, true, 4, &mut rng), 4);
        assert_eq!(next_level(6, true, true, 4, &mut rng), 7);
        let redrawn: Vec<usize> = (0..400)
            .map(|_| next_level(LEVELS - 1, true, true, 4, &mut rng))
            .collect();
        assert!(redrawn.iter().all(|&l| (4..LEVELS).contains(&l)), "{redrawn:?}");
        assert!(
            redrawn.contains(&4) && redrawn.contains(&(LEVELS - 1)),
            "the whole range above the floor"
        );
        let unfloored: Vec<usize> = (0..400)
            .map(|_| next_level(LEVELS - 1, true, true, 0, &mut rng))
            .collect();
        assert!(
            unfloored.contains(&0),
            "without a floor the top redraws over every level"
        );
        // A floor past the top is the top.
        assert_eq!(next_level(2, false, false, 99, &mut rng), LEVELS - 1);
        assert!(Column::Up.climbs() && Column::OutdoorUp.climbs());
        assert!(!Column::Down.climbs() && !Column::OutdoorDown.climbs() && !Column::Flat.climbs());
    }

    #[test]
    fn a_review_draws_every_level_from_the_floor_to_the_frontier_and_only_those() {
        let mut rng = Rng(11);
        assert_eq!(episode_level(7, 0, false, &mut rng), 7, "no review: the frontier");
        let drawn: Vec<usize> = (0..600).map(|_| episode_level(7, 2, true, &mut rng)).collect();
        for l in 2..=7 {
            assert!(drawn.contains(&l), "level {l} never drawn: {drawn:?}");
        }
        assert!(drawn.iter().all(|&l| (2..=7).contains(&l)), "{drawn:?}");
        // A floor above the level, or a level past the top, stays in range.
        assert_eq!(episode_level(1, 4, true, &mut rng), 1);
        assert_eq!(episode_level(99, 0, false, &mut rng), LEVELS - 1);
    }

    #[test]
    fn environments_split_into_the_mix_s_columns() {
        let n = 128;
        let mixes = [(FLAT_SHARE, UP_SHARE), (0.3, UP_SHARE), (0.3, 0.7)];
        for mix in mixes.map(|(flat, up)| ColumnMix { flat, up }) {
            let count = |c: Column| (0..n).filter(|&i| Column::for_env(i, n, None, mix) == c).count();
            for (c, share) in Column::mix(mix) {
                let want = share * n as f64;
                let got = count(c) as f64;
                assert!(
                    (got - want).abs() <= 1.0,
                    "{mix:?}, {c:?}: {got} environments, want {want}"
                );
            }
            let shares = Column::mix(mix);
            assert!((shares.iter().map(|m| m.1).sum::<f64>() - 1.0).abs() < 1e-12);
            let climbing = shares[1].1 + shares[3].1;
            assert!(
                (climbing / (1.0 - mix.flat) - mix.up).abs() < 1e-12,
                "{mix:?}: up {climbing}"
            );
            // Each side keeps the table's indoor : outdoor ratio.
            let ratio = |m: &[(Column, f64); 5], indoor: usize, outdoor: usize| m[indoor].1 / m[outdoor].1;
            for (indoor, outdoor) in [(1, 3), (2, 4)] {
                let (got, table) = (ratio(&shares, indoor, outdoor), ratio(&Column::MIX, indoor, outdoor));
                assert!((got - table).abs() < 1e-12, "{mix:?}: {got} against {table}");
            }
        }
        assert_eq!(
            Column::mix(ColumnMix::default()),
            Column::MIX,
            "the default mix is the table, bit for bit"
        );
        let up_per_down = |m: [(Column, f64); 5]| m[1].1 / m[2].1;
        let flat_03 = ColumnMix {
            flat: 0.3,
            ..ColumnMix::default()
        };
        assert_eq!(up_per_down(Column::mix(flat_03)), up_per_down(Column::MIX));
        let up_07 = ColumnMix { flat: 0.3, up: 0.7 };
        assert!((up_per_down(Column::mix(up_07)) - 0.7 / 0.3).abs() < 1e-12);
        assert!((0..n).all(|i| Column::for_env(i, n, Some(Column::Up), flat_03) == Column::Up));
    }
}
