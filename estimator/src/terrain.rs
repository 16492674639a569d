//! Geometric (no learning) terrain estimator: the paper's terrain token z = (class, h, d, θ) from
//! one BEV grid ([`sensor_io::bev`]), used by the firmware as the fallback when the CNN's token is
//! implausible (see [`plausible`]).
//!
//! Algorithm, per grid (deterministic, allocation-free after [`GeometricTerrainEstimator::new`]):
//! 1. collect the occupied cells (x, y, z = mean) that are finite, outside the self-hit box around
//!    the robot and not outliers (|z| or max − min too large);
//! 2. stair direction: connected regions of cells at one level (treads, landings, floor) vote with
//!    their minor axis (elongated, narrow regions weigh most) for a first guess; around it (± 20°,
//!    2° then 0.25° steps; all of [−90°, 90°) without a guess) the cells within
//!    `lateral_half_width_m` across the direction u = (cos φ, sin φ) are binned along u (2 cm) and
//!    the φ with the smallest within-bin / total height variance wins (a staircase's height depends
//!    on the coordinate along u alone; the band keeps the floor beside a narrow staircase out);
//! 3. the 1-D profile (median height per bin) is cut into plateaus: a bin joins the current plateau
//!    when it is within `level_tol_m` of the plateau's local level and no data gap separates them;
//!    short plateaus (riser cells, noise) are dropped, neighbours closer than `min_jump_m` merged;
//! 4. risers = jumps between consecutive plateaus, except jumps above 0.30 m per step that fits in
//!    the gap between them (drops beside a staircase or a platform); a riser seen from above
//!    (higher plateau on the robot's side) lies at the edge of the higher plateau (the lower tread
//!    is shadowed next to it),
//!    one seen from below in the middle of the gap (filled by the riser face's mixed cells, which
//!    step 1 drops); the majority sign of the jumps along u gives up/down;
//!    h = median jump (jumps across data gaps divided by their step count), d = median spacing of
//!    consecutive risers, or, with fewer than two risers, the rise over run of the plateau centres,
//!    or `default_depth_m`;
//! 5. class: stairs when a riser (or the data gap that hides one, if it can be one step or steps of
//!    its sign were seen) crosses the look-ahead box, else flat; yaw θ = −φ (the token's
//!    convention: the stairs run at −θ in the robot frame), with u always pointing forward
//!    (x ≥ 0), so |θ| ≤ 90°.
use hal::{wrap_angle, TerrainClass, TerrainToken};
use sensor_io::bev::{BevGrid, BEV_CELLS, CH_MEAN, CH_RANGE};

/// Cells in one grid.
pub const MAX_CELLS: usize = BEV_CELLS * BEV_CELLS;
/// Profile half-length along the stair direction, m (the window's corner is 2.12 m away).
const PROFILE_HALF_M: f32 = 2.15;
/// Profile bins at most (the bin width is clamped so that the profile fits).
const MAX_BINS: usize = 448;
/// Plateaus at most (more are dropped; a staircase in the window has < 25).
const MAX_SEGS: usize = 96;
/// Level differences above this are boundaries (side drops of a staircase or a platform), not
/// risers, m (steps are at most 0.25 m + 10 % jitter).
const MAX_STEP_M: f32 = 0.30;
/// Shallowest tread, m (bounds the steps hidden in a data gap).
const MIN_TREAD_M: f32 = 0.18;
/// Neighbouring cells within this height difference belong to one tread (level region), m.
const TREAD_TOL_M: f32 = 0.025;
/// Level regions with fewer cells do not vote for the direction.
const TREAD_MIN_CELLS: usize = 8;
/// The direction scan covers the tread direction ± this, degrees.
const DIR_WINDOW_DEG: f32 = 20.0;
/// The direction scan needs at least this many cells in the band.
const DIR_MIN_CELLS: u32 = 40;
/// Height noise variance added to both sides of the direction score's variance ratio, m².
const DIR_NOISE_M2: f64 = 0.01 * 0.01;

/// Thresholds of the geometric estimator. Heights are in the BEV frame (z = 0 under the robot).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GeometricTerrainConfig {
    /// Cells with |x| and |y| both below this are ignored (self-hits on legs and arms), m.
    pub self_box_half_m: f32,
    /// Cells with |mean z| above this are ignored as garbage, m.
    pub max_abs_z_m: f32,
    /// Cells whose max − min exceeds this are ignored (riser faces, mixed returns, spray): their
    /// mean is neither tread's height, m.
    pub max_cell_range_m: f32,
    /// Fewer usable cells than this: flat with zero confidence.
    pub min_cells: usize,
    /// The direction scan uses the cells within this distance of the robot (a disc, so that every
    /// direction is scored on the same cells), m.
    pub direction_radius_m: f32,
    /// Only cells within this distance across the stair direction score a direction and make the
    /// profile (narrow staircases: a smaller band keeps the ground beside them out), m.
    pub lateral_half_width_m: f32,
    /// Coarse direction scan step over [−90°, 90°), degrees.
    pub coarse_step_deg: f32,
    /// Fine direction scan step within ± one coarse step of the best, degrees.
    pub fine_step_deg: f32,
    /// Profile bin along the stair direction, m (≥ 0.01).
    pub profile_bin_m: f32,
    /// A bin joins the current plateau when within this of its local level, m.
    pub level_tol_m: f32,
    /// Plateaus differing by less than this are one level; a riser is at least this high, m.
    pub min_jump_m: f32,
    /// A data gap longer than this along the profile ends a plateau, m.
    pub max_gap_m: f32,
    /// Plateaus shorter than this along the profile are dropped (riser cells, noise), m.
    pub min_plateau_m: f32,
    /// Plateaus with fewer cells than this are dropped.
    pub min_plateau_cells: usize,
    /// A riser whose plateaus are further apart than this has an unknown position (inside the gap), m.
    pub max_riser_gap_m: f32,
    /// Look-ahead box in the robot frame: x range and half width, m. Stairs iff a riser crosses it.
    pub lookahead_x_min_m: f32,
    pub lookahead_x_max_m: f32,
    pub lookahead_half_width_m: f32,
    /// Step depth reported when neither riser spacing nor a slope is observable, m.
    pub default_depth_m: f32,
}

impl Default for GeometricTerrainConfig {
    fn default() -> Self {
        Self {
            self_box_half_m: 0.4,
            max_abs_z_m: 2.5,
            max_cell_range_m: 0.06,
            min_cells: 60,
            direction_radius_m: 3.0,
            lateral_half_width_m: 1.2,
            coarse_step_deg: 2.0,
            fine_step_deg: 0.25,
            profile_bin_m: 0.02,
            level_tol_m: 0.02,
            min_jump_m: 0.03,
            max_gap_m: 0.08,
            min_plateau_m: 0.06,
            min_plateau_cells: 6,
            max_riser_gap_m: 0.3,
            lookahead_x_min_m: -0.5,
            lookahead_x_max_m: 1.5,
            lookahead_half_width_m: 0.75,
            default_depth_m: 0.3,
        }
    }
}

/// One estimate: the token and how much to trust it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TerrainEstimate {
    pub token: TerrainToken,
    /// 0 (no information) … 1; heuristic: data amount, sign agreement of the risers, spread of the
    /// jumps, whether the depth was measured.
    pub confidence: f32,
    /// Occupied cells that passed the filters.
    pub cells_used: u32,
    /// Height levels (plateaus) found along the stair direction.
    pub levels: u32,
    /// Risers (jumps between consecutive levels) found, either sign.
    pub risers: u32,
    /// RMS height residual about the 1-D profile at the chosen direction, m.
    pub fit_residual_m: f32,
    /// The depth comes from riser spacing (true) or from a slope / the default (false).
    pub depth_measured: bool,
}

/// Whether a token is physically plausible: finite; stairs with h ∈ [0.02, 0.35] m,
/// d ∈ [0.12, 0.7] m and |θ| < 90°; flat with h = d = 0.
pub fn plausible(token: &TerrainToken) -> bool {
    if !token.is_finite() {
        return false;
    }
    match token.class {
        TerrainClass::Flat => token.step_height_m == 0.0 && token.step_depth_m == 0.0,
        TerrainClass::StairsUp | TerrainClass::StairsDown => {
            (0.02..=0.35).contains(&token.step_height_m)
                && (0.12..=0.7).contains(&token.step_depth_m)
                && token.yaw_rad.abs() < core::f32::consts::FRAC_PI_2
        }
    }
}

#[derive(Clone, Copy, Debug, Default)]
struct Plateau {
    /// First and last profile bin.
    b0: u16,
    b1: u16,
    nbins: u16,
    ncells: u32,
    level: f32,
}

#[derive(Clone, Copy, Debug, Default)]
struct Riser {
    dz: f32,
    /// Position along u, m.
    s: f32,
    /// Interval that contains the riser (the data gap between the plateaus, or s ± one bin), m.
    s_lo: f32,
    s_hi: f32,
    /// Data gap between the plateaus small enough for `s` to be the riser's position.
    located: bool,
}

/// Fixed working memory (boxed once).
struct Scratch {
    x: [f32; MAX_CELLS],
    y: [f32; MAX_CELLS],
    z: [f32; MAX_CELLS],
    s: [f32; MAX_CELLS],
    order: [u16; MAX_CELLS],
    tmp: [f32; MAX_CELLS],
    bin_n: [u32; MAX_BINS],
    bin_sum: [f64; MAX_BINS],
    bin_sq: [f64; MAX_BINS],
    bin_med: [f32; MAX_BINS],
    segs: [Plateau; MAX_SEGS],
    levels: [Plateau; MAX_SEGS],
    risers: [Riser; MAX_SEGS],
    vals: [f32; MAX_SEGS],
    /// Grid cell (ix * 60 + iy) → usable cell index, or `NONE`.
    cell_idx: [u16; MAX_CELLS],
    /// Usable cell → grid cell.
    grid_idx: [u16; MAX_CELLS],
    /// Component visited flag per usable cell; flood-fill stack.
    seen: [bool; MAX_CELLS],
    stack: [u16; MAX_CELLS],
}

const NONE: u16 = u16::MAX;

/// The geometric terrain estimator. Construct once; [`estimate`](Self::estimate) does not allocate.
pub struct GeometricTerrainEstimator {
    cfg: GeometricTerrainConfig,
    bin_m: f32,
    nbins: usize,
    w: Box<Scratch>,
}

/// Median of `v` (reordered in place); NaN-free input; 0 for an empty slice.
fn median(v: &mut [f32]) -> f32 {
    let n = v.len();
    if n == 0 {
        return 0.0;
    }
    let (_, m, _) = v.select_nth_unstable_by(n / 2, f32::total_cmp);
    let hi = *m;
    if n % 2 == 1 {
        hi
    } else {
        let lo = v[..n / 2].iter().copied().fold(f32::NEG_INFINITY, f32::max);
        0.5 * (lo + hi)
    }
}

impl GeometricTerrainEstimator {
    pub fn new(cfg: GeometricTerrainConfig) -> Self {
        let min_bin = 2.0 * PROFILE_HALF_M / MAX_BINS as f32;
        let bin_m = if cfg.profile_bin_m.is_finite() {
            cfg.profile_bin_m.max(min_bin)
        } else {
            0.02
        };
        let nbins = ((2.0 * PROFILE_HALF_M / bin_m).ceil() as usize).min(MAX_BINS);
        let w = Box::new(Scratch {
            x: [0.0; MAX_CELLS],
            y: [0.0; MAX_CELLS],
            z: [0.0; MAX_CELLS],
            s: [0.0; MAX_CELLS],
            order: [0; MAX_CELLS],
            tmp: [0.0; MAX_CELLS],
            bin_n: [0; MAX_BINS],
            bin_sum: [0.0; MAX_BINS],
            bin_sq: [0.0; MAX_BINS],
            bin_med: [0.0; MAX_BINS],
            segs: [Plateau::default(); MAX_SEGS],
            levels: [Plateau::default(); MAX_SEGS],
            risers: [Riser::default(); MAX_SEGS],
            vals: [0.0; MAX_SEGS],
            cell_idx: [NONE; MAX_CELLS],
            grid_idx: [0; MAX_CELLS],
            seen: [false; MAX_CELLS],
            stack: [0; MAX_CELLS],
        });
        Self { cfg, bin_m, nbins, w }
    }

    pub fn config(&self) -> &GeometricTerrainConfig {
        &self.cfg
    }

    /// Terrain token from one BEV grid. Never panics; garbage or too little data gives flat with
    /// zero confidence.
    pub fn estimate(&mut self, grid: &BevGrid) -> TerrainEstimate {
        let n = self.collect(grid);
        let mut out = TerrainEstimate {
            token: TerrainToken::FLAT,
            cells_used: n as u32,
            ..Default::default()
        };
        if n < self.cfg.min_cells.max(1) {
            return out;
        }
        let data_conf = (n as f32 / (4.0 * self.cfg.min_cells.max(1) as f32)).min(1.0);

        // Direction: the treads' orientation (connected level regions) gives a first guess; the
        // profile sharpness refines it within ± DIR_WINDOW_DEG (a full scan when there is no guess).
        let coarse = self.cfg.coarse_step_deg.clamp(0.1, 15.0);
        let fine = self.cfg.fine_step_deg.clamp(0.01, coarse);
        let mut best = (f64::INFINITY, 0.0f32);
        let (lo, steps) = match self.tread_direction(n) {
            Some(g) => (g - DIR_WINDOW_DEG, (2.0 * DIR_WINDOW_DEG / coarse).round() as i32 + 1),
            None => (-90.0, (180.0 / coarse).round() as i32),
        };
        for k in 0..steps {
            let phi = lo + k as f32 * coarse;
            let sc = self.direction_score(n, phi.to_radians());
            if sc < best.0 {
                best = (sc, phi);
            }
        }
        let centre = best.1;
        let fsteps = (coarse / fine).round() as i32;
        for k in -fsteps..=fsteps {
            if k == 0 {
                continue;
            }
            let phi = centre + k as f32 * fine;
            let sc = self.direction_score(n, phi.to_radians());
            if sc < best.0 {
                best = (sc, phi);
            }
        }
        // u must point forward: fold φ into [−90°, 90°].
        let mut phi = best.1;
        while phi < -90.0 {
            phi += 180.0;
        }
        while phi > 90.0 {
            phi -= 180.0;
        }
        out.fit_residual_m = if best.0.is_finite() {
            best.0.max(0.0).sqrt() as f32
        } else {
            0.0
        };
        let phi_rad = phi.to_radians();

        // Profile, plateaus, risers.
        let m = self.profile(n, phi_rad);
        if m == 0 {
            return out;
        }
        let nseg = self.plateaus();
        let nlev = self.merge_levels(nseg);
        let nris = self.risers(nlev);
        out.levels = nlev as u32;
        out.risers = nris as u32;
        out.confidence = data_conf * if nris == 0 { 1.0 } else { 0.6 };
        if nris == 0 {
            return out;
        }

        // Up or down along u: majority sign of the jumps (ties: their sum).
        let w = &mut *self.w;
        let (mut pos, mut neg, mut sum) = (0usize, 0usize, 0.0f32);
        for r in &w.risers[..nris] {
            if r.dz > 0.0 {
                pos += 1;
            } else {
                neg += 1;
            }
            sum += r.dz;
        }
        let up = pos > neg || (pos == neg && sum > 0.0);
        let sign = if up { 1.0 } else { -1.0 };
        let agree = pos.max(neg) as f32 / nris as f32;

        // Is a riser (of the staircase's sign) within the look-ahead box?
        let (c, s) = (libm::cosf(phi_rad), libm::sinf(phi_rad));
        let mut box_lo = f32::INFINITY;
        let mut box_hi = f32::NEG_INFINITY;
        for (bx, by) in [
            (self.cfg.lookahead_x_min_m, -self.cfg.lookahead_half_width_m),
            (self.cfg.lookahead_x_min_m, self.cfg.lookahead_half_width_m),
            (self.cfg.lookahead_x_max_m, -self.cfg.lookahead_half_width_m),
            (self.cfg.lookahead_x_max_m, self.cfg.lookahead_half_width_m),
        ] {
            let p = bx * c + by * s;
            box_lo = box_lo.min(p);
            box_hi = box_hi.max(p);
        }
        // A jump across a data gap counts only when it can be one step, or when steps of its sign
        // were seen elsewhere (else it is a drop beside a platform or staircase).
        let seen_located = w.risers[..nris].iter().any(|r| r.dz * sign > 0.0 && r.located);
        let in_box = w.risers[..nris].iter().any(|r| {
            r.dz * sign > 0.0
                && (r.located || seen_located || r.dz.abs() <= MAX_STEP_M)
                && r.s_hi >= box_lo
                && r.s_lo <= box_hi
        });
        if !in_box {
            out.confidence = data_conf * 0.5 * agree;
            return out;
        }

        // Step height: median of the single-step jumps of the staircase's sign; a jump across a
        // data gap counts as round(|dz| / h0) steps.
        let mut k = 0;
        for r in &w.risers[..nris] {
            if r.dz * sign > 0.0 && r.located {
                w.vals[k] = r.dz.abs();
                k += 1;
            }
        }
        if k == 0 {
            for r in &w.risers[..nris] {
                if r.dz * sign > 0.0 {
                    w.vals[k] = r.dz.abs();
                    k += 1;
                }
            }
            // Across gaps only: the smallest jump is the best guess of one step.
            let mn = w.vals[..k].iter().copied().fold(f32::INFINITY, f32::min);
            w.vals[0] = mn;
            k = 1;
        }
        let h0 = median(&mut w.vals[..k]);
        k = 0;
        for r in &w.risers[..nris] {
            if r.dz * sign > 0.0 {
                let steps = (r.dz.abs() / h0).round().max(1.0);
                w.vals[k] = r.dz.abs() / steps;
                k += 1;
            }
        }
        let h = median(&mut w.vals[..k]);
        let mut spread = 0.0f32;
        for v in &mut w.vals[..k] {
            *v = (*v - h).abs();
        }
        if k >= 3 {
            spread = median(&mut w.vals[..k]) / h.max(1e-3);
        }

        // Step depth: spacing of consecutive located single-step risers of the staircase's sign.
        k = 0;
        for i in 1..nris {
            let (a, b) = (w.risers[i - 1], w.risers[i]);
            if a.located
                && b.located
                && a.dz * sign > 0.0
                && b.dz * sign > 0.0
                && (a.dz.abs() / h0).round() <= 1.0
                && (b.dz.abs() / h0).round() <= 1.0
            {
                let sp = b.s - a.s;
                if (0.08..=1.0).contains(&sp) {
                    w.vals[k] = sp;
                    k += 1;
                }
            }
        }
        let (d, measured) = if k > 0 {
            (median(&mut w.vals[..k]), true)
        } else {
            // Rise over run of the plateau centres (only inner plateaus are whole treads).
            let mut dd = self.cfg.default_depth_m;
            if nlev >= 3 {
                let first = w.levels[1];
                let last = w.levels[nlev - 2];
                if nlev >= 4 {
                    let cf = (first.b0 as f32 + first.b1 as f32 + 1.0) * 0.5 * self.bin_m;
                    let cl = (last.b0 as f32 + last.b1 as f32 + 1.0) * 0.5 * self.bin_m;
                    let rise = (last.level - first.level).abs();
                    let nsteps = (rise / h).round();
                    if nsteps >= 1.0 {
                        dd = (cl - cf).abs() / nsteps;
                    }
                } else {
                    // One whole tread between two risers (not located): its extent bounds d.
                    dd = (first.b1 as f32 - first.b0 as f32 + 1.0) * self.bin_m;
                }
            }
            (dd, false)
        };

        out.token = TerrainToken {
            class: if up {
                TerrainClass::StairsUp
            } else {
                TerrainClass::StairsDown
            },
            step_height_m: h,
            step_depth_m: d,
            yaw_rad: wrap_angle(-(phi_rad as f64)) as f32,
        };
        out.confidence = data_conf
            * agree
            * (1.0 - spread.min(0.5))
            * if measured { 1.0 } else { 0.6 }
            * if nris >= 2 { 1.0 } else { 0.7 };
        out
    }

    /// Usable cells into the scratch arrays; returns their count.
    fn collect(&mut self, grid: &BevGrid) -> usize {
        let cfg = &self.cfg;
        let w = &mut *self.w;
        let mut n = 0;
        w.cell_idx.fill(NONE);
        for ix in 0..BEV_CELLS {
            for iy in 0..BEV_CELLS {
                let dens = grid.get(sensor_io::bev::CH_DENSITY, ix, iy);
                // Also rejects NaN.
                if dens.is_nan() || dens <= 0.0 {
                    continue;
                }
                let z = grid.get(CH_MEAN, ix, iy);
                let range = grid.get(CH_RANGE, ix, iy);
                if !z.is_finite() || z.abs() > cfg.max_abs_z_m || !range.is_finite() || range > cfg.max_cell_range_m {
                    continue;
                }
                let (x, y) = BevGrid::cell_center(ix, iy);
                if x.abs() < cfg.self_box_half_m && y.abs() < cfg.self_box_half_m {
                    continue;
                }
                w.x[n] = x;
                w.y[n] = y;
                w.z[n] = z;
                w.cell_idx[ix * BEV_CELLS + iy] = n as u16;
                w.grid_idx[n] = (ix * BEV_CELLS + iy) as u16;
                n += 1;
            }
        }
        n
    }

    /// Stair direction guess, degrees in [−90°, 90°): connected regions of cells at one level
    /// (8-neighbours within `TREAD_TOL_M`) are treads, landings or floor; an elongated region's
    /// minor axis is the stair direction. Axial mean weighted by cells × elongation², narrow
    /// regions (treads) preferred. None without elongated regions.
    fn tread_direction(&mut self, n: usize) -> Option<f32> {
        let w = &mut *self.w;
        w.seen[..n].fill(false);
        let (mut ac, mut as_) = (0.0f64, 0.0f64);
        for seed in 0..n {
            if w.seen[seed] {
                continue;
            }
            w.seen[seed] = true;
            w.stack[0] = seed as u16;
            let mut top = 1;
            let (mut k, mut sx, mut sy, mut sxx, mut syy, mut sxy) = (0u32, 0.0f64, 0.0f64, 0.0f64, 0.0f64, 0.0f64);
            while top > 0 {
                top -= 1;
                let i = w.stack[top] as usize;
                let (x, y) = (w.x[i] as f64, w.y[i] as f64);
                k += 1;
                sx += x;
                sy += y;
                sxx += x * x;
                syy += y * y;
                sxy += x * y;
                let g = w.grid_idx[i] as usize;
                let (ix, iy) = ((g / BEV_CELLS) as isize, (g % BEV_CELLS) as isize);
                for dx in -1isize..=1 {
                    for dy in -1isize..=1 {
                        let (px, py) = (ix + dx, iy + dy);
                        if px < 0 || py < 0 || px >= BEV_CELLS as isize || py >= BEV_CELLS as isize {
                            continue;
                        }
                        let j = w.cell_idx[px as usize * BEV_CELLS + py as usize];
                        if j == NONE || w.seen[j as usize] {
                            continue;
                        }
                        if (w.z[j as usize] - w.z[i]).abs() <= TREAD_TOL_M {
                            w.seen[j as usize] = true;
                            w.stack[top] = j;
                            top += 1;
                        }
                    }
                }
            }
            if (k as usize) < TREAD_MIN_CELLS {
                continue;
            }
            let kf = k as f64;
            let (mx, my) = (sx / kf, sy / kf);
            let (a, c, b) = (sxx / kf - mx * mx, syy / kf - my * my, sxy / kf - mx * my);
            let r = (0.25 * (a - c) * (a - c) + b * b).sqrt();
            let tr = a + c;
            if tr <= 0.0 || r <= 0.0 {
                continue;
            }
            let elong = 2.0 * r / tr;
            let minor_sd = (0.5 * tr - r).max(0.0).sqrt();
            let wgt = kf * elong * elong * if minor_sd < 0.2 { 1.0 } else { 0.1 };
            // Minor axis in doubled-angle form: −(cos 2θ_major, sin 2θ_major).
            ac -= wgt * (a - c) / (2.0 * r);
            as_ -= wgt * b / r;
        }
        if ac * ac + as_ * as_ <= 0.0 {
            return None;
        }
        Some((0.5 * libm::atan2(as_, ac)).to_degrees() as f32)
    }

    /// Mean within-bin height variance of the profile along φ (smaller = sharper).
    fn direction_score(&mut self, n: usize, phi: f32) -> f64 {
        let (c, s) = (libm::cosf(phi), libm::sinf(phi));
        let r2 = self.cfg.direction_radius_m * self.cfg.direction_radius_m;
        let inv = 1.0 / self.bin_m;
        let nb = self.nbins;
        let w = &mut *self.w;
        w.bin_n[..nb].fill(0);
        w.bin_sum[..nb].fill(0.0);
        w.bin_sq[..nb].fill(0.0);
        let lat = self.cfg.lateral_half_width_m;
        let mut used = 0u32;
        let (mut tot, mut tot2) = (0.0f64, 0.0f64);
        for i in 0..n {
            let (x, y) = (w.x[i], w.y[i]);
            if x * x + y * y > r2 || (-x * s + y * c).abs() > lat {
                continue;
            }
            tot += w.z[i] as f64;
            tot2 += (w.z[i] as f64) * (w.z[i] as f64);
            let b = ((x * c + y * s + PROFILE_HALF_M) * inv) as usize;
            if b >= nb {
                continue;
            }
            let z = w.z[i] as f64;
            w.bin_n[b] += 1;
            w.bin_sum[b] += z;
            w.bin_sq[b] += z * z;
            used += 1;
        }
        if used < DIR_MIN_CELLS {
            return f64::INFINITY;
        }
        let mut sse = 0.0;
        for b in 0..nb {
            let k = w.bin_n[b];
            if k > 1 {
                sse += w.bin_sq[b] - w.bin_sum[b] * w.bin_sum[b] / k as f64;
            }
        }
        let sst = tot2 - tot * tot / used as f64;
        (sse + DIR_NOISE_M2 * used as f64) / (sst + DIR_NOISE_M2 * used as f64)
    }

    /// Sorts the cells in the lateral band by their coordinate along φ and stores each bin's
    /// median height in `bin_med` (`bin_n` = cells). Returns the cells used.
    fn profile(&mut self, n: usize, phi: f32) -> usize {
        let (c, s) = (libm::cosf(phi), libm::sinf(phi));
        let lat = self.cfg.lateral_half_width_m;
        let nb = self.nbins;
        let inv = 1.0 / self.bin_m;
        let w = &mut *self.w;
        let mut m = 0;
        for i in 0..n {
            let (x, y) = (w.x[i], w.y[i]);
            if (-x * s + y * c).abs() > lat {
                continue;
            }
            w.s[i] = x * c + y * s;
            w.order[m] = i as u16;
            m += 1;
        }
        let (order, sv) = (&mut w.order[..m], &w.s);
        order.sort_unstable_by(|&a, &b| sv[a as usize].total_cmp(&sv[b as usize]).then(a.cmp(&b)));
        w.bin_n[..nb].fill(0);
        let mut j = 0;
        while j < m {
            let b = ((w.s[w.order[j] as usize] + PROFILE_HALF_M) * inv) as usize;
            let mut e = j;
            let mut k = 0;
            while e < m && ((w.s[w.order[e] as usize] + PROFILE_HALF_M) * inv) as usize == b {
                w.tmp[k] = w.z[w.order[e] as usize];
                k += 1;
                e += 1;
            }
            if b < nb {
                w.bin_n[b] = k as u32;
                w.bin_med[b] = median(&mut w.tmp[..k]);
            }
            j = e;
        }
        m
    }

    /// Cuts the profile into plateaus (`segs`); returns how many survive the length/cell filters.
    fn plateaus(&mut self) -> usize {
        let cfg = &self.cfg;
        let max_gap = (cfg.max_gap_m / self.bin_m).round().max(1.0) as usize;
        let min_bins = (cfg.min_plateau_m / self.bin_m).round().max(1.0) as usize;
        let w = &mut *self.w;
        let mut nseg = 0;
        let mut cur: Option<Plateau> = None;
        let mut recent = [0.0f32; 3];
        let mut nrecent = 0usize;
        let push = |p: Plateau, segs: &mut [Plateau; MAX_SEGS], nseg: &mut usize| {
            if p.nbins as usize >= min_bins && p.ncells as usize >= cfg.min_plateau_cells && *nseg < MAX_SEGS {
                segs[*nseg] = p;
                *nseg += 1;
            }
        };
        for b in 0..self.nbins {
            if w.bin_n[b] == 0 {
                continue;
            }
            let v = w.bin_med[b];
            let joins = match cur {
                Some(p) => {
                    let k = nrecent.min(3);
                    let local = recent[..k].iter().sum::<f32>() / k as f32;
                    b - p.b1 as usize <= max_gap && (v - local).abs() <= cfg.level_tol_m
                }
                None => false,
            };
            if joins {
                let p = cur.as_mut().unwrap_or_else(|| unreachable!());
                p.b1 = b as u16;
                p.nbins += 1;
                p.ncells += w.bin_n[b];
            } else {
                if let Some(p) = cur {
                    push(p, &mut w.segs, &mut nseg);
                }
                cur = Some(Plateau {
                    b0: b as u16,
                    b1: b as u16,
                    nbins: 1,
                    ncells: w.bin_n[b],
                    level: 0.0,
                });
                nrecent = 0;
            }
            recent[nrecent % 3] = v;
            nrecent += 1;
        }
        if let Some(p) = cur {
            push(p, &mut w.segs, &mut nseg);
        }
        // Level of each plateau: median of its bin medians.
        for i in 0..nseg {
            let p = w.segs[i];
            let mut k = 0;
            for b in p.b0 as usize..=p.b1 as usize {
                if w.bin_n[b] > 0 {
                    w.tmp[k] = w.bin_med[b];
                    k += 1;
                }
            }
            w.segs[i].level = median(&mut w.tmp[..k]);
        }
        nseg
    }

    /// Merges consecutive plateaus closer than `min_jump_m` into levels (`levels`).
    fn merge_levels(&mut self, nseg: usize) -> usize {
        let w = &mut *self.w;
        let mut nlev = 0;
        for i in 0..nseg {
            let p = w.segs[i];
            if nlev > 0 && (p.level - w.levels[nlev - 1].level).abs() < self.cfg.min_jump_m {
                let q = &mut w.levels[nlev - 1];
                let (wq, wp) = (q.nbins as f32, p.nbins as f32);
                q.level = (q.level * wq + p.level * wp) / (wq + wp);
                q.b1 = p.b1;
                q.nbins += p.nbins;
                q.ncells += p.ncells;
            } else {
                w.levels[nlev] = p;
                nlev += 1;
            }
        }
        nlev
    }

    /// Risers between consecutive levels (`risers`); returns their count.
    fn risers(&mut self, nlev: usize) -> usize {
        let bin = self.bin_m;
        let max_gap = self.cfg.max_riser_gap_m;
        let w = &mut *self.w;
        let mut nr = 0;
        for i in 1..nlev {
            let (a, b) = (w.levels[i - 1], w.levels[i]);
            let dz = b.level - a.level;
            let a_end = (a.b1 as f32 + 1.0) * bin - PROFILE_HALF_M;
            let b_start = b.b0 as f32 * bin - PROFILE_HALF_M;
            // A jump larger than the steps that fit in the gap between the plateaus is a drop to
            // the floor beside a staircase or a platform, not a step.
            let fit = 1.0 + ((b_start - a_end) / MIN_TREAD_M).max(0.0).floor();
            if dz.abs() > MAX_STEP_M * fit {
                continue;
            }
            // Seen from above (higher plateau on the robot's side), the lower tread is shadowed
            // next to the riser: the riser is at the higher plateau's edge. Seen from below, the
            // riser face fills the gap (its cells are dropped as mixed): the middle of the gap.
            let (hi_near, s_hi_edge) = if dz > 0.0 {
                (b_start < 0.0, b_start)
            } else {
                (a_end > 0.0, a_end)
            };
            let s = if hi_near { s_hi_edge } else { 0.5 * (a_end + b_start) };
            let located = b_start - a_end <= max_gap;
            let (s_lo, s_hi) = if located { (s - bin, s + bin) } else { (a_end, b_start) };
            w.risers[nr] = Riser {
                dz,
                s,
                s_lo,
                s_hi,
                located,
            };
            nr += 1;
        }
        nr
    }
}

snapshot::snapshot_fields!(TerrainEstimate {
    token,
    confidence,
    cells_used,
    levels,
    risers,
    fit_residual_m,
    depth_measured,
});
