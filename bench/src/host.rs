//! The benchmark's own process as Linux shows it in `/proc`: CPU time per
//! thread (so that the gateway's share can be told from the simulated
//! devices' and the client's when all run in one process) and resident
//! memory; and how a benchmark's outcome becomes the exit status.

use anyhow::Result;
use std::process::ExitCode;

/// Clock ticks per second of the `/proc` CPU times (`USER_HZ`, 100 on
/// every Linux this runs on).
const TICKS_PER_SECOND: f64 = 100.0;

/// The CPU time of every thread of this process: (thread name, user plus
/// system seconds). Thread names come from the runtimes' `thread_name`.
pub fn thread_cpu() -> std::io::Result<Vec<(String, f64)>> {
    threads_cpu_of("self")
}

/// [`thread_cpu`] of another process (`pid`): (thread id, name, seconds).
pub fn process_thread_cpu(pid: u32) -> std::io::Result<Vec<(u32, String, f64)>> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(format!("/proc/{pid}/task"))? {
        let entry = entry?;
        let Some(tid) = entry.file_name().to_str().and_then(|t| t.parse().ok()) else {
            continue;
        };
        let dir = entry.path();
        let comm = std::fs::read_to_string(dir.join("comm")).unwrap_or_default();
        let stat = std::fs::read_to_string(dir.join("stat")).unwrap_or_default();
        if let Some(secs) = stat_cpu_seconds(&stat) {
            out.push((tid, comm.trim().to_string(), secs));
        }
    }
    Ok(out)
}

fn threads_cpu_of(pid: &str) -> std::io::Result<Vec<(String, f64)>> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(format!("/proc/{pid}/task"))? {
        let dir = entry?.path();
        let comm = std::fs::read_to_string(dir.join("comm")).unwrap_or_default();
        let stat = std::fs::read_to_string(dir.join("stat")).unwrap_or_default();
        if let Some(secs) = stat_cpu_seconds(&stat) {
            out.push((comm.trim().to_string(), secs));
        }
    }
    Ok(out)
}

/// User plus system seconds of process `pid` so far, all its threads
/// (those that ended included) from `/proc/<pid>/stat`: the CPU a server
/// spent, for a process that is not this one.
pub fn process_cpu_seconds(pid: u32) -> std::io::Result<f64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat"))?;
    stat_cpu_seconds(&stat).ok_or_else(|| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            "unexpected /proc stat line",
        )
    })
}

/// The processes `pid` started that still run, from
/// `/proc/<pid>/task/<pid>/children` (empty when the kernel does not
/// provide that file).
pub fn child_pids(pid: u32) -> Vec<u32> {
    std::fs::read_to_string(format!("/proc/{pid}/task/{pid}/children"))
        .unwrap_or_default()
        .split_whitespace()
        .filter_map(|p| p.parse().ok())
        .collect()
}

/// User plus system seconds of a `/proc/<pid>/task/<tid>/stat` line.
fn stat_cpu_seconds(stat: &str) -> Option<f64> {
    // Fields after the ")" of the command name (which may hold spaces):
    // utime is the 12th, stime the 13th (fields 14 and 15 of the line).
    let (_, rest) = stat.rsplit_once(')')?;
    let f: Vec<&str> = rest.split_whitespace().collect();
    if f.len() < 13 {
        return None;
    }
    let ticks = f[11].parse::<f64>().unwrap_or(0.0) + f[12].parse::<f64>().unwrap_or(0.0);
    Some(ticks / TICKS_PER_SECOND)
}

/// The CPU seconds of the threads of `threads` ([`thread_cpu`]) whose name
/// starts with one of `prefixes`.
pub fn cpu_seconds(threads: &[(String, f64)], prefixes: &[&str]) -> f64 {
    threads
        .iter()
        .filter(|(name, _)| prefixes.iter().any(|p| name.starts_with(p)))
        .map(|(_, secs)| secs)
        .sum()
}

/// A `kB` line of `/proc/<pid>/status` (`VmRSS`, `VmHWM`, …; `Threads`
/// has no unit but reads the same).
pub fn status_kib(status: &str, key: &str) -> Option<u64> {
    status
        .lines()
        .find_map(|l| l.strip_prefix(key)?.strip_prefix(':'))
        .and_then(|rest| rest.split_whitespace().next()?.parse().ok())
}

/// This process's resident set size in KiB (the gateway and the load
/// clients, when both run here).
pub fn rss_kib() -> Option<u64> {
    status_kib(&std::fs::read_to_string("/proc/self/status").ok()?, "VmRSS")
}

/// The exit status of a benchmark binary whose run returned whether its
/// targets were met: 1 when it could not run (the error goes to stderr
/// after `bench`), and with `strict` also when a target was missed.
pub fn exit_code(bench: &str, strict: bool, result: Result<bool>) -> ExitCode {
    match result {
        Ok(met) if met || !strict => ExitCode::SUCCESS,
        Ok(_) => ExitCode::FAILURE,
        Err(e) => {
            eprintln!("{bench}: {e:#}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_proc_status() {
        let s = "Name:\tcangate-server\nVmHWM:\t   20480 kB\nVmRSS:\t   12345 kB\nThreads:\t5\n";
        assert_eq!(status_kib(s, "VmRSS"), Some(12345));
        assert_eq!(status_kib(s, "VmHWM"), Some(20480));
        assert_eq!(status_kib(s, "Threads"), Some(5));
        assert_eq!(status_kib(s, "VmSwap"), None);
    }

    #[test]
    fn parses_thread_stat() {
        // A command name with a space and a parenthesis, utime 250 and
        // stime 50 ticks.
        let stat = "42 (sync-can0 (x)) S 1 1 1 0 -1 4194368 100 0 0 0 250 50 0 0 20 0 1 0";
        assert_eq!(stat_cpu_seconds(stat), Some(3.0));
        assert_eq!(stat_cpu_seconds("42 (short) S 1"), None);
        let threads = vec![
            ("gateway-1".to_string(), 1.0),
            ("sync-can0".to_string(), 0.5),
            ("client".to_string(), 2.0),
        ];
        assert_eq!(cpu_seconds(&threads, &["gateway", "sync-"]), 1.5);
        assert_eq!(cpu_seconds(&threads, &["none"]), 0.0);
    }

    #[test]
    fn reads_this_process() {
        assert!(rss_kib().is_some_and(|k| k > 0));
        let threads = thread_cpu().expect("/proc/self/task");
        assert!(!threads.is_empty());
    }
}
