//! Real-time set-up of the control thread on the robot: SCHED_FIFO priority, CPU pinning and
//! locked memory. Each step is optional and fails with an error that says what privilege is missing.

#[derive(Clone, Copy, Debug, Default)]
pub struct RtOptions {
    /// SCHED_FIFO priority (1..=99) for the calling (control) thread.
    pub fifo_priority: Option<i32>,
    /// Pin the calling thread to this CPU.
    pub cpu: Option<usize>,
    /// Lock current and future memory (no page faults on the tick path).
    pub mlockall: bool,
}

#[derive(Debug, thiserror::Error)]
pub enum RtError {
    #[error("SCHED_FIFO priority must be 1..=99, got {0}")]
    Priority(i32),
    #[error("CPU {cpu} is not available (this machine has CPUs 0..{n})")]
    Cpu { cpu: usize, n: usize },
    #[error("{what} failed{hint}")]
    Os {
        what: &'static str,
        source: std::io::Error,
        hint: &'static str,
    },
}

fn os(what: &'static str, hint: &'static str) -> RtError {
    RtError::Os {
        what,
        source: std::io::Error::last_os_error(),
        hint,
    }
}

/// Applies `opts` to the calling thread (and, for mlockall, the process).
pub fn apply(opts: &RtOptions) -> Result<(), RtError> {
    if opts.mlockall {
        // SAFETY: mlockall takes flags only and touches no memory of ours.
        if unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) } != 0 {
            return Err(os(
                "mlockall",
                " (needs CAP_IPC_LOCK or a large enough `ulimit -l`; run as root or raise memlock in /etc/security/limits.conf)",
            ));
        }
    }
    if let Some(cpu) = opts.cpu {
        let n = std::thread::available_parallelism().map_or(1, |n| n.get());
        if cpu >= libc::CPU_SETSIZE as usize {
            return Err(RtError::Cpu { cpu, n });
        }
        // SAFETY: cpu_set_t is plain data; zeroed is its empty set, CPU_SET stays within it
        // (checked against CPU_SETSIZE above), and the pointer passed is valid for its size.
        let r = unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            libc::CPU_SET(cpu, &mut set);
            libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set)
        };
        if r != 0 {
            let e = std::io::Error::last_os_error();
            if e.raw_os_error() == Some(libc::EINVAL) {
                return Err(RtError::Cpu { cpu, n });
            }
            return Err(RtError::Os {
                what: "sched_setaffinity",
                source: e,
                hint: "",
            });
        }
    }
    if let Some(p) = opts.fifo_priority {
        if !(1..=99).contains(&p) {
            return Err(RtError::Priority(p));
        }
        let param = libc::sched_param { sched_priority: p };
        // SAFETY: the pointer is to a valid, initialised sched_param that outlives the call.
        if unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) } != 0 {
            return Err(os(
                "sched_setscheduler(SCHED_FIFO)",
                " (needs CAP_SYS_NICE: run as root, `setcap cap_sys_nice+ep g1fw`, or raise rtprio in limits.conf)",
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pinning_to_cpu0_works_and_bad_values_are_refused() {
        // Run in a scratch thread so the test harness's thread keeps its affinity.
        std::thread::spawn(|| {
            apply(&RtOptions {
                cpu: Some(0),
                ..Default::default()
            })
            .expect("pinning to CPU 0 is always allowed");
            let e = apply(&RtOptions {
                cpu: Some(100_000),
                ..Default::default()
            })
            .unwrap_err();
            assert!(e.to_string().contains("not available"), "{e}");
            let e = apply(&RtOptions {
                fifo_priority: Some(0),
                ..Default::default()
            })
            .unwrap_err();
            assert!(e.to_string().contains("1..=99"), "{e}");
        })
        .join()
        .unwrap();
    }

    #[test]
    fn fifo_either_works_or_says_which_capability_is_missing() {
        std::thread::spawn(|| {
            match apply(&RtOptions {
                fifo_priority: Some(10),
                ..Default::default()
            }) {
                Ok(()) => {}
                Err(e) => assert!(e.to_string().contains("CAP_SYS_NICE"), "{e}"),
            }
        })
        .join()
        .unwrap();
    }
}
