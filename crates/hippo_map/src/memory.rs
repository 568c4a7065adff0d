//! How much memory a sparse factorisation may take, checked before anything that size is allocated.
//!
//! A pose graph whose loop closures join far-apart vertices fills its Cholesky factor in: 10⁶ random
//! long closures on 10⁵ vertices make it all but dense, 3.5·10¹¹ bytes. Allocating that aborts the
//! process (Rust's allocation failure is not an error one can catch), taking a Python interpreter and
//! everything it had not saved with it. The factor's size is known from the pattern alone, in time
//! linear in it ([`crate::sparse::BlockOrdering`]), so the solve refuses with [`MapError::FactorTooLarge`]
//! instead.
//!
//! The limit is [`crate::SolverParams::max_factor_bytes`] when set, else what the system has available
//! now: on Linux the lesser of `MemAvailable` in `/proc/meminfo` and the room left under this process's
//! cgroup memory limit (a container's), elsewhere an assumed [`ASSUMED_AVAILABLE_BYTES`].
use crate::error::{MapError, Result};

/// Factorisations up to this size are never refused by the available-memory check: reading the system's
/// memory state costs more than solving a small graph, and any machine that runs the package has it.
const ALWAYS_ALLOWED_BYTES: u64 = 64 << 20;
/// What is assumed available where the system does not say (not Linux): conservative, so that a graph
/// that needs more is refused with a message naming `max_factor_bytes` rather than aborting the process.
pub(crate) const ASSUMED_AVAILABLE_BYTES: u64 = 4 << 30;
/// cgroup "no limit" reads as a huge number (v1: 2⁶³ rounded to a page); anything above this is none.
const NO_CGROUP_LIMIT_BYTES: u64 = 1 << 60;

/// What a factorisation may take: the caller's cap, or else what the system has available, less what
/// runs alongside it (the chordal initialisation's factor and the solve's are built at the same time).
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct MemoryBudget {
    /// [`crate::SolverParams::max_factor_bytes`].
    pub cap_bytes: Option<u64>,
    /// Bytes another factorisation running at the same time needs.
    pub alongside_bytes: u64,
}

impl MemoryBudget {
    /// Refuse when `needed_bytes` (plus what runs alongside) exceeds the limit.
    pub fn check(&self, needed_bytes: u64) -> Result<()> {
        let needed_bytes = needed_bytes.saturating_add(self.alongside_bytes);
        let (limit_bytes, limit) = match self.cap_bytes {
            Some(cap) => (cap, "the cap max_factor_bytes"),
            None if needed_bytes <= ALWAYS_ALLOWED_BYTES => return Ok(()),
            None => available_bytes(),
        };
        if needed_bytes <= limit_bytes {
            Ok(())
        } else {
            Err(MapError::FactorTooLarge {
                needed_bytes,
                limit_bytes,
                limit,
            })
        }
    }
}

/// Memory available to this process now, and where the number comes from (for the error message).
pub(crate) fn available_bytes() -> (u64, &'static str) {
    let Some(mem_available) = mem_available_bytes() else {
        return (
            ASSUMED_AVAILABLE_BYTES,
            "what is assumed available (the system does not report its free memory)",
        );
    };
    match cgroup_room_bytes() {
        Some(room) if room < mem_available => (
            room,
            "the room left under this process's cgroup memory limit",
        ),
        _ => (mem_available, "the memory available (MemAvailable)"),
    }
}

/// `MemAvailable` of `/proc/meminfo` (Linux ≥ 3.14), in bytes.
fn mem_available_bytes() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let mut words = line.split_whitespace().skip(1);
    let value: u64 = words.next()?.parse().ok()?;
    match words.next() {
        Some("kB") => value.checked_mul(1024),
        None => Some(value),
        Some(_) => None,
    }
}

/// Limit minus usage of this process's memory cgroup (v2, then v1), where it has a limit. Inside a
/// container the cgroup file system is usually the container's own, mounted at its root, so the
/// process's own path is tried first and the root second.
fn cgroup_room_bytes() -> Option<u64> {
    let own = std::fs::read_to_string("/proc/self/cgroup").unwrap_or_default();
    let read =
        |path: String| -> Option<u64> { std::fs::read_to_string(path).ok()?.trim().parse().ok() };
    let room = |dir: &str, limit: &str, usage: &str| -> Option<u64> {
        let limit_bytes = read(format!("{dir}/{limit}"))?;
        let usage_bytes = read(format!("{dir}/{usage}"))?;
        (limit_bytes < NO_CGROUP_LIMIT_BYTES).then(|| limit_bytes.saturating_sub(usage_bytes))
    };
    for line in own.lines() {
        // "0::/path" (v2) or "4:memory:/path" (v1).
        let mut fields = line.splitn(3, ':');
        let (_, controllers, path) = (fields.next(), fields.next()?, fields.next()?);
        let found = if controllers.is_empty() {
            room(
                &format!("/sys/fs/cgroup{path}"),
                "memory.max",
                "memory.current",
            )
            .or_else(|| room("/sys/fs/cgroup", "memory.max", "memory.current"))
        } else if controllers.split(',').any(|c| c == "memory") {
            let (limit, usage) = ("memory.limit_in_bytes", "memory.usage_in_bytes");
            room(&format!("/sys/fs/cgroup/memory{path}"), limit, usage)
                .or_else(|| room("/sys/fs/cgroup/memory", limit, usage))
        } else {
            None
        };
        if found.is_some() {
            return found;
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cap_refuses_above_it_and_counts_what_runs_alongside() {
        let budget = MemoryBudget {
            cap_bytes: Some(1000),
            alongside_bytes: 0,
        };
        assert!(budget.check(1000).is_ok());
        let err = budget.check(1001).unwrap_err();
        assert!(
            matches!(
                err,
                MapError::FactorTooLarge {
                    needed_bytes: 1001,
                    limit_bytes: 1000,
                    ..
                }
            ),
            "{err}"
        );
        let alongside = MemoryBudget {
            cap_bytes: Some(1000),
            alongside_bytes: 600,
        };
        assert!(alongside.check(500).is_err());
        assert!(alongside.check(400).is_ok());
    }

    #[test]
    fn small_factorisations_pass_without_a_cap_and_the_system_reports_something() {
        assert!(MemoryBudget::default().check(1 << 20).is_ok());
        let (bytes, source) = available_bytes();
        assert!(bytes > 0, "{source}");
        if cfg!(target_os = "linux") {
            assert!(mem_available_bytes().is_some());
        }
    }
}
