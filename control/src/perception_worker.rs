//! The perception step on its own thread, so its ~1–1.6 ms (more on the robot's CPU) never sits in
//! the 2 ms tick. Deterministic by construction: the tick thread hands the whole [`Perception`]
//! (its frame already loaded) to the worker on a perception tick `k` and takes the result back at
//! the fixed tick `k + L`, before that tick's policy group; the poses recorded in between are
//! added to its history when it comes home, in order, so every step sees exactly the inputs it
//! would have seen inline. A result not ready at `k + L` is *late*: counted, its token not used
//! (the policy keeps the last one), and the log says so, so replay makes the same choice. Only
//! that choice depends on thread timing, and it is recorded.
//!
//! Hand-over is a mutex-guarded slot holding a `Box` and a condition variable: no allocation
//! after start, no channel.
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;

use crate::perception::Estimate;

use crate::perception::{Perception, PerceptionSummary};

/// How the runtime runs the perception step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PerceptionExec {
    /// In the tick, after the command (the token reaches the next policy step).
    Inline,
    /// On a worker thread; the result is consumed `consume_after` ticks after the frame.
    /// `wait`: block for a result that is not ready at that tick instead of calling it late
    /// (simulation, where time is the simulator's and a wait costs nothing but wall time).
    Threaded { consume_after: u32, wait: bool },
}

impl PerceptionExec {
    /// `inline`, `threaded` (10 ticks) or `threaded:L`.
    pub fn parse(s: &str, wait: bool) -> Result<Self, String> {
        match s {
            "inline" => Ok(Self::Inline),
            "threaded" => Ok(Self::Threaded {
                consume_after: DEFAULT_CONSUME_AFTER,
                wait,
            }),
            _ => match s.strip_prefix("threaded:").map(str::parse::<u32>) {
                Some(Ok(l)) if l >= 1 => Ok(Self::Threaded { consume_after: l, wait }),
                _ => Err(format!(
                    "perception '{s}': use `inline`, `threaded` (result used {DEFAULT_CONSUME_AFTER} ticks after the frame) or `threaded:TICKS`"
                )),
            },
        }
    }

    /// As recorded in the log's metadata (`perception_exec`): `inline` or `threaded:L`.
    pub fn label(&self) -> String {
        match self {
            Self::Inline => "inline".into(),
            Self::Threaded { consume_after, .. } => format!("threaded:{consume_after}"),
        }
    }
}

/// 20 ms at 500 Hz: ten times the step's measured 1.1–1.6 ms on x86, room for the robot's CPU, and
/// one policy period (the token is at most one policy step later than inline).
pub const DEFAULT_CONSUME_AFTER: u32 = 10;

struct Job {
    perception: Box<Perception>,
    now_ns: u64,
    estimate: Estimate,
}

#[derive(Default)]
struct Slot {
    job: Option<Job>,
    done: Option<(Box<Perception>, PerceptionSummary)>,
    stop: bool,
    /// The step panicked (a bug): its message. The perception state went with it.
    failed: Option<String>,
    /// Tests only: the next step panics.
    panic_next: bool,
}

struct Shared {
    slot: Mutex<Slot>,
    changed: Condvar,
}

fn lock(s: &Shared) -> MutexGuard<'_, Slot> {
    s.slot.lock().unwrap_or_else(|e| e.into_inner())
}

/// The thread that runs [`Perception::step`].
pub struct PerceptionWorker {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

impl PerceptionWorker {
    pub fn start() -> std::io::Result<Self> {
        let shared = Arc::new(Shared {
            slot: Mutex::new(Slot::default()),
            changed: Condvar::new(),
        });
        let sh = shared.clone();
        let thread = std::thread::Builder::new()
            .name("perception".into())
            .spawn(move || work(&sh))?;
        Ok(Self {
            shared,
            thread: Some(thread),
        })
    }

    /// Hands `perception` (with its frame loaded) over for a step at `now_ns`.
    pub fn submit(&self, perception: Box<Perception>, now_ns: u64, estimate: Estimate) {
        let mut slot = lock(&self.shared);
        slot.job = Some(Job {
            perception,
            now_ns,
            estimate,
        });
        drop(slot);
        self.shared.changed.notify_all();
    }

    /// The finished step, if it is.
    ///
    /// A step that panicked on the worker panics here, on the control thread, where `run_loop`'s
    /// guard damps the motors: the worker must not die quietly and leave the policy an old token
    /// (or `take` waiting forever).
    pub fn try_take(&self) -> Option<(Box<Perception>, PerceptionSummary)> {
        let mut slot = lock(&self.shared);
        failed(&slot);
        slot.done.take()
    }

    /// Tests only: the next step panics on the worker (see [`PerceptionWorker::try_take`]).
    #[doc(hidden)]
    pub fn inject_panic(&self) {
        lock(&self.shared).panic_next = true;
    }

    /// Waits for the step to finish.
    pub fn take(&self) -> (Box<Perception>, PerceptionSummary) {
        let mut slot = lock(&self.shared);
        loop {
            failed(&slot);
            if let Some(d) = slot.done.take() {
                return d;
            }
            slot = self.shared.changed.wait(slot).unwrap_or_else(|e| e.into_inner());
        }
    }
}

impl Drop for PerceptionWorker {
    fn drop(&mut self) {
        lock(&self.shared).stop = true;
        self.shared.changed.notify_all();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn failed(slot: &Slot) {
    if let Some(why) = &slot.failed {
        panic!("the perception worker panicked: {why}");
    }
}

fn work(shared: &Shared) {
    let mut slot = lock(shared);
    loop {
        if slot.stop {
            return;
        }
        if let Some(mut job) = slot.job.take() {
            let inject = std::mem::take(&mut slot.panic_next);
            drop(slot);
            let step = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                if inject {
                    panic!("injected by PerceptionWorker::inject_panic");
                }
                job.perception.step(job.now_ns, true, &job.estimate)
            }));
            slot = lock(shared);
            match step {
                Ok(summary) => slot.done = Some((job.perception, summary)),
                Err(payload) => {
                    slot.failed = Some(crate::panic_message(payload.as_ref()));
                    shared.changed.notify_all();
                    return;
                }
            }
            shared.changed.notify_all();
            continue;
        }
        slot = shared.changed.wait(slot).unwrap_or_else(|e| e.into_inner());
    }
}
