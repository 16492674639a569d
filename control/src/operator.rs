//! Operator commands: the velocity command, emergency stop and reset, per control tick.
//!
//! A schedule file gives piecewise-constant commands over simulated time (the paper's
//! velocity-tracking experiment), one line per change:
//!
//! ```text
//! # t_s   vx    vy    wz        (m/s, m/s, rad/s; '#' starts a comment)
//! 0.0     0.0   0.0   0.0
//! 2.0     0.5   0.0   0.0
//! 8.0     estop                 # latch damping
//! 9.0     reset                 # leave damping: fresh start-up from the current pose
//! ```
//! Times must increase. A command holds until the next line; `estop`/`reset` act on one tick, as
//! do the requests of an operated run (`stand_up`, `walk`, `stand`, `sit_down`, `passive`).
use std::path::{Path, PathBuf};

use hal::{LowState, TickTime};

/// Largest command-schedule file read, bytes (a schedule is a few lines per command change).
pub const MAX_SCHEDULE_BYTES: u64 = 1 << 20;

/// Gain of the heading correction: yaw rate per radian of heading error (legged_gym's heading
/// command uses 0.5 · wrap(target − yaw)).
pub const HEADING_K: f32 = 0.5;
/// Largest yaw rate the heading correction commands, rad/s (inside every spec's command range we
/// ship; the peer walker tracks 0.5 rad/s).
pub const HEADING_WZ_MAX: f32 = 0.5;

/// Forward velocity with heading correction: `[vx, 0, clamp(K · wrap(target_yaw − yaw), ±WZ_MAX)]`
/// ([`HEADING_K`], [`HEADING_WZ_MAX`]). `target_yaw` and `yaw` in rad in the same frame; the
/// firmware passes the yaw of the IMU quaternion it reads ([`imu_yaw`]), never ground truth.
/// The one definition: `g1fw sim --heading`, `g1fw eval` and the PPO trainer call it.
pub fn heading_command(vx: f32, target_yaw: f32, yaw: f32) -> [f32; 3] {
    let err = hal::wrap_angle((target_yaw - yaw) as f64) as f32;
    let wz = (HEADING_K * err).clamp(-HEADING_WZ_MAX, HEADING_WZ_MAX);
    // NaN in (a bad IMU) → NaN out: the supervisor latches damping on a non-finite command.
    [vx, 0.0, if err.is_nan() { f32::NAN } else { wz }]
}

/// Gain of the line hold: heading offset (rad) per metre across the line.
pub const LINE_K: f32 = 1.0;
/// Largest heading offset the line hold asks for, rad (≈ 29°).
pub const LINE_MAX_RAD: f32 = 0.5;

/// Signed distance (m, left positive) of `(x, y)` from the line through the start (0, 0) along
/// `target_yaw`: the one definition of "the line" (the line hold steers by it, the trainer's
/// drift penalty charges it).
pub fn left_of_line(target_yaw: f32, x: f32, y: f32) -> f32 {
    -libm::sinf(target_yaw) * x + libm::cosf(target_yaw) * y
}

/// The heading that steers back to the line through the start (0, 0) along `target_yaw`, from
/// the robot's position `(x, y)` in the same frame: the target turned toward the line by
/// `LINE_K` rad per metre across it ([`left_of_line`]), at most [`LINE_MAX_RAD`]. What an
/// operator does who keeps the robot on a staircase's centre line; heading hold alone lets a
/// sideways drift grow. A non-finite position gives the plain target (heading hold as before).
pub fn line_heading(target_yaw: f32, x: f32, y: f32) -> f32 {
    let left = left_of_line(target_yaw, x, y);
    if !left.is_finite() {
        return target_yaw;
    }
    target_yaw - (LINE_K * left).clamp(-LINE_MAX_RAD, LINE_MAX_RAD)
}

/// Yaw (rad) of the IMU's quaternion (w, x, y, z) as the firmware reads it.
pub fn imu_yaw(state: &LowState) -> f32 {
    let [w, x, y, z] = state.imu.quaternion;
    libm::atan2f(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
}

/// What the operator asks for on one tick.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct OperatorInput {
    /// vx, vy (m/s), wz (rad/s) in the body frame.
    pub velocity: [f32; 3],
    pub estop: bool,
    pub reset: bool,
    /// A change of state the operator asks for this tick (an operated run's state machine,
    /// [`crate::controller::Mode`]).
    pub request: Option<Request>,
}

/// The operator's transitions of an operated run (as every G1 deploy tool has them: unitree_rl_lab's
/// Passive → FixStand → Velocity, rl_sar's GetUp / GetDown).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Request {
    /// Passive → ramp to the default pose, then stand.
    StandUp,
    /// Standing → the policy walks.
    Walk,
    /// Walking → ramp back to the default pose and stand.
    Stand,
    /// Standing or walking → ramp to the pose the robot stood up from, then passive.
    SitDown,
    /// Any state → passive (damping, no fault); after a trip, the operator's acknowledgement.
    Passive,
}

impl Request {
    pub const ALL: [Request; 5] = [
        Request::StandUp,
        Request::Walk,
        Request::Stand,
        Request::SitDown,
        Request::Passive,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Request::StandUp => "stand_up",
            Request::Walk => "walk",
            Request::Stand => "stand",
            Request::SitDown => "sit_down",
            Request::Passive => "passive",
        }
    }

    pub fn from_name(s: &str) -> Option<Request> {
        Request::ALL.into_iter().find(|r| r.name() == s)
    }
}

/// A source of operator input, asked once per tick.
pub trait OperatorSource {
    fn at(&mut self, tick: TickTime) -> OperatorInput;
    /// [`OperatorSource::at`] with the tick's newest state (what `run_loop` calls), for operators
    /// that close a loop on the robot's own sensors (the heading command).
    fn at_state(&mut self, tick: TickTime, _state: &LowState) -> OperatorInput {
        self.at(tick)
    }
    /// [`OperatorSource::at_state`] with the estimator's newest base estimate (from the previous
    /// tick), for operators that close a loop on where the robot is (the line hold).
    fn at_estimate(&mut self, tick: TickTime, state: &LowState, _estimate: &estimator::BaseEstimate) -> OperatorInput {
        self.at_state(tick, state)
    }
}

/// A schedule's commands with the heading correction applied every tick: the schedule's vx (its vy
/// and wz are replaced) and [`heading_command`] towards `target_yaw` from the IMU's yaw. Estop and
/// reset pass through. The result is recorded as `/operator/command`, so replay repeats it exactly.
pub struct HeadingSource<S> {
    pub inner: S,
    /// Target heading, rad, in the IMU's yaw frame (the world frame in simulation: the robot starts
    /// at yaw 0).
    pub target_yaw: f32,
    /// Also steer back to the line through the start along `target_yaw` ([`line_heading`]), from
    /// the estimator's base position (leg odometry; never ground truth).
    pub hold_line: bool,
}

impl<S: OperatorSource> OperatorSource for HeadingSource<S> {
    fn at(&mut self, tick: TickTime) -> OperatorInput {
        self.inner.at(tick)
    }
    fn at_state(&mut self, tick: TickTime, state: &LowState) -> OperatorInput {
        let mut op = self.inner.at_state(tick, state);
        op.velocity = heading_command(op.velocity[0], self.target_yaw, imu_yaw(state));
        op
    }
    fn at_estimate(&mut self, tick: TickTime, state: &LowState, estimate: &estimator::BaseEstimate) -> OperatorInput {
        if !self.hold_line {
            return self.at_state(tick, state);
        }
        let mut op = self.inner.at_estimate(tick, state, estimate);
        let [x, y, _] = estimate.position;
        let target = if estimate.valid {
            line_heading(self.target_yaw, x, y)
        } else {
            self.target_yaw
        };
        op.velocity = heading_command(op.velocity[0], target, imu_yaw(state));
        op
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ScheduleError {
    #[error("cannot read command schedule {path}")]
    Read { path: PathBuf, source: std::io::Error },
    #[error("command schedule {path}, line {line}: {message}")]
    Line {
        path: PathBuf,
        line: usize,
        message: String,
    },
    #[error("command schedule {path} has no command lines")]
    Empty { path: PathBuf },
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Step {
    Velocity([f32; 3]),
    EStop,
    Reset,
    Request(Request),
}

/// Piecewise-constant operator commands over time.
#[derive(Clone, Debug, PartialEq)]
pub struct CommandSchedule {
    /// (start time in s, step), times increasing.
    pub steps: Vec<(f64, Step)>,
    /// Where it came from (for logs); `None` for a constant command.
    pub source: Option<PathBuf>,
}

impl CommandSchedule {
    /// The same velocity command for the whole run.
    pub fn constant(velocity: [f32; 3]) -> Self {
        Self {
            steps: vec![(0.0, Step::Velocity(velocity))],
            source: None,
        }
    }

    /// Refuses steps that start at or after the run's end (`duration_s`): they would never take
    /// effect, and a run that silently ignores part of its schedule measures something else.
    pub fn check_within(&self, duration_s: f64) -> Result<(), String> {
        match self.steps.iter().find(|(t, _)| *t > 0.0 && *t >= duration_s) {
            Some((t, _)) => Err(format!(
                "{}: a step starts at {t} s, at or after the run's end ({duration_s} s): lengthen --duration or \
                 remove the step",
                self.source
                    .as_ref()
                    .map_or("the command schedule".into(), |p| p.display().to_string())
            )),
            None => Ok(()),
        }
    }

    /// Reads a schedule file (at most [`MAX_SCHEDULE_BYTES`]).
    pub fn load(path: &Path) -> Result<Self, ScheduleError> {
        let text = crate::read_text_capped(path, MAX_SCHEDULE_BYTES).map_err(|source| ScheduleError::Read {
            path: path.into(),
            source,
        })?;
        Self::parse(&text, path)
    }

    pub fn parse(text: &str, path: &Path) -> Result<Self, ScheduleError> {
        let err = |line: usize, message: String| ScheduleError::Line {
            path: path.into(),
            line,
            message,
        };
        let mut steps: Vec<(f64, Step)> = Vec::new();
        for (i, raw) in text.lines().enumerate() {
            let line = raw.split('#').next().unwrap_or("").trim();
            if line.is_empty() {
                continue;
            }
            let fields: Vec<&str> = line.split([' ', '\t', ',']).filter(|f| !f.is_empty()).collect();
            let t: f64 = fields[0]
                .parse()
                .map_err(|e| err(i + 1, format!("time '{}': {e}", fields[0])))?;
            if !(t.is_finite() && t >= 0.0) {
                return Err(err(i + 1, format!("time must be a non-negative number, got {t}")));
            }
            if let Some(&(prev, _)) = steps.last() {
                if t <= prev {
                    return Err(err(i + 1, format!("time {t} s does not come after {prev} s")));
                }
            }
            let step = match &fields[1..] {
                ["estop"] => Step::EStop,
                ["reset"] => Step::Reset,
                [word] if Request::from_name(word).is_some() => Step::Request(Request::from_name(word).expect("matched")),
                [vx, vy, wz] => {
                    let mut v = [0f32; 3];
                    for (k, s) in [vx, vy, wz].iter().enumerate() {
                        v[k] = s.parse().map_err(|e| err(i + 1, format!("'{s}': {e}")))?;
                        if !v[k].is_finite() {
                            return Err(err(i + 1, format!("'{s}' is not a finite number")));
                        }
                    }
                    Step::Velocity(v)
                }
                _ => {
                    return Err(err(
                        i + 1,
                        format!(
                            "expected 'T VX VY WZ', 'T estop', 'T reset' or 'T REQUEST' (stand_up, walk, stand, sit_down, passive), got '{line}'"
                        ),
                    ))
                }
            };
            steps.push((t, step));
        }
        if steps.is_empty() {
            return Err(ScheduleError::Empty { path: path.into() });
        }
        Ok(Self {
            steps,
            source: Some(path.into()),
        })
    }

    /// The velocity commanded at time `t` (zero before the first command).
    pub fn velocity_at(&self, t: f64) -> [f32; 3] {
        let mut v = [0.0; 3];
        for &(ts, step) in &self.steps {
            if ts > t + 1e-12 {
                break;
            }
            if let Step::Velocity(c) = step {
                v = c;
            }
        }
        v
    }

    /// Start times of velocity changes (for per-segment evaluation).
    pub fn velocity_segments(&self) -> Vec<(f64, [f32; 3])> {
        self.steps
            .iter()
            .filter_map(|&(t, s)| match s {
                Step::Velocity(v) => Some((t, v)),
                _ => None,
            })
            .collect()
    }

    /// A per-tick source over this schedule (no allocation per tick).
    pub fn source(&self, control_dt_ns: u64) -> ScheduleSource<'_> {
        ScheduleSource {
            schedule: self,
            next: 0,
            control_dt_ns,
            current: OperatorInput::default(),
        }
    }
}

/// Walks a schedule tick by tick. A step applies from the first tick whose time is at or after its
/// start time (tick times are integers of nanoseconds, so the rule is exact).
pub struct ScheduleSource<'a> {
    schedule: &'a CommandSchedule,
    next: usize,
    control_dt_ns: u64,
    current: OperatorInput,
}

impl OperatorSource for ScheduleSource<'_> {
    fn at(&mut self, tick: TickTime) -> OperatorInput {
        self.current.estop = false;
        self.current.reset = false;
        self.current.request = None;
        let t_ns = tick.index * self.control_dt_ns;
        while let Some(&(ts, step)) = self.schedule.steps.get(self.next) {
            if ((ts * 1e9).round() as u64) > t_ns {
                break;
            }
            match step {
                Step::Velocity(v) => self.current.velocity = v,
                Step::EStop => self.current.estop = true,
                Step::Reset => self.current.reset = true,
                Step::Request(r) => self.current.request = Some(r),
            }
            self.next += 1;
        }
        self.current
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tick(index: u64) -> TickTime {
        TickTime {
            index,
            time_ns: index * 2_000_000,
        }
    }

    #[test]
    fn parses_and_walks() {
        let s = CommandSchedule::parse(
            "# header\n0 0 0 0\n1.0 0.5, 0, 0.1  # walk\n2.0 estop\n2.004 reset\n",
            Path::new("x"),
        )
        .unwrap();
        assert_eq!(s.steps.len(), 4);
        let mut src = s.source(2_000_000);
        assert_eq!(src.at(tick(0)).velocity, [0.0; 3]);
        assert_eq!(src.at(tick(499)).velocity, [0.0; 3]);
        assert_eq!(src.at(tick(500)).velocity, [0.5, 0.0, 0.1]);
        assert!(!src.at(tick(999)).estop);
        let at = src.at(tick(1000));
        assert!(at.estop && !at.reset && at.velocity == [0.5, 0.0, 0.1]);
        assert!(!src.at(tick(1001)).estop);
        assert!(src.at(tick(1002)).reset);
        assert!(!src.at(tick(1003)).reset);
        assert_eq!(s.velocity_at(1.5), [0.5, 0.0, 0.1]);
    }

    #[test]
    fn heading_command_turns_towards_the_target_and_saturates() {
        use std::f32::consts::PI;
        assert_eq!(heading_command(0.5, 0.0, 0.0), [0.5, 0.0, 0.0]);
        // 0.4 rad to the left of the robot: turn left at K · 0.4.
        let c = heading_command(0.5, 0.4, 0.0);
        assert!(
            c[0] == 0.5 && c[1] == 0.0 && (c[2] - HEADING_K * 0.4).abs() < 1e-6,
            "{c:?}"
        );
        assert!((heading_command(0.3, 0.0, 0.4)[2] + HEADING_K * 0.4).abs() < 1e-6);
        // Large errors saturate.
        assert_eq!(heading_command(0.5, 3.0, 0.0)[2], HEADING_WZ_MAX);
        assert_eq!(heading_command(0.5, -3.0, 0.0)[2], -HEADING_WZ_MAX);
        // Wrapping: from yaw 3.0 to target −3.0 is +0.28 rad (left), not −6 rad.
        let c = heading_command(0.5, -3.0, 3.0)[2];
        assert!((c - HEADING_K * (2.0 * PI - 6.0)).abs() < 1e-5, "{c}");
        assert!(heading_command(0.5, 0.0, f32::NAN)[2].is_nan());
    }

    #[test]
    fn heading_source_uses_the_imu_yaw_and_keeps_estop() {
        let s = CommandSchedule::parse("0 0.4 0.2 0.3\n0.01 estop\n", Path::new("x")).unwrap();
        let mut h = HeadingSource {
            inner: s.source(2_000_000),
            target_yaw: 0.2,
            hold_line: false,
        };
        let mut st = LowState::default();
        // Yaw 0.6 rad about z.
        st.imu.quaternion = [libm::cosf(0.3), 0.0, 0.0, libm::sinf(0.3)];
        assert!((imu_yaw(&st) - 0.6).abs() < 1e-6);
        let op = h.at_state(tick(0), &st);
        assert!(op.velocity[0] == 0.4 && op.velocity[1] == 0.0, "{op:?}");
        assert!((op.velocity[2] + HEADING_K * 0.4).abs() < 1e-6, "{op:?}");
        assert!(h.at_state(tick(5), &st).estop);
    }

    #[test]
    fn line_heading_turns_back_towards_the_line_and_saturates() {
        // On the line (anywhere along it): the target itself.
        assert_eq!(line_heading(0.0, 2.0, 0.0), 0.0);
        let h = 0.4f32;
        assert!((line_heading(h, 3.0 * libm::cosf(h), 3.0 * libm::sinf(h)) - h).abs() < 1e-6);
        // 0.2 m left of a line along +x: turn right by K · 0.2; right of it, left.
        assert!((line_heading(0.0, 1.0, 0.2) + LINE_K * 0.2).abs() < 1e-6);
        assert!((line_heading(0.0, 1.0, -0.2) - LINE_K * 0.2).abs() < 1e-6);
        // Across a line at 90°, "left" is −x.
        assert!(
            (line_heading(std::f32::consts::FRAC_PI_2, -0.1, 1.0) - (std::f32::consts::FRAC_PI_2 - LINE_K * 0.1)).abs()
                < 1e-6
        );
        // Far off: at most LINE_MAX_RAD. A non-finite position: the plain target.
        assert_eq!(line_heading(0.0, 0.0, 5.0), -LINE_MAX_RAD);
        assert_eq!(line_heading(0.0, 0.0, -5.0), LINE_MAX_RAD);
        assert_eq!(line_heading(0.3, f32::NAN, 0.0), 0.3);
    }

    #[test]
    fn heading_source_holds_the_line_from_the_estimate_only_when_asked() {
        let s = CommandSchedule::parse("0 0.5 0 0\n", Path::new("x")).unwrap();
        let st = LowState::default(); // yaw 0
        let mut est = estimator::BaseEstimate {
            valid: true,
            ..Default::default()
        };
        est.position = [1.0, 0.4, 0.0]; // 0.4 m left of the line along +x
        let mut plain = HeadingSource {
            inner: s.source(2_000_000),
            target_yaw: 0.0,
            hold_line: false,
        };
        assert_eq!(plain.at_estimate(tick(0), &st, &est).velocity, [0.5, 0.0, 0.0]);
        let mut line = HeadingSource {
            inner: s.source(2_000_000),
            target_yaw: 0.0,
            hold_line: true,
        };
        let wz = line.at_estimate(tick(0), &st, &est).velocity[2];
        assert!((wz + HEADING_K * LINE_K * 0.4).abs() < 1e-6, "{wz}");
        // An estimate the estimator marks invalid is not steered on.
        est.valid = false;
        assert_eq!(line.at_estimate(tick(0), &st, &est).velocity, [0.5, 0.0, 0.0]);
    }

    #[test]
    fn rejects_bad_lines_with_line_numbers() {
        for (text, want) in [
            ("1 0 0 0\n0.5 0 0 0\n", "line 2"),
            ("0 0 0\n", "expected"),
            ("0 nan 0 0\n", "finite"),
            ("x 0 0 0\n", "time 'x'"),
            ("# nothing\n", "no command lines"),
        ] {
            let e = CommandSchedule::parse(text, Path::new("s.txt"))
                .unwrap_err()
                .to_string();
            assert!(e.contains(want), "{text:?}: {e}");
        }
    }
}
