//! What the running process has used: CPU time for the timing lines of benches and examples.

/// CPU seconds this process has used so far, user + system over every thread (Linux
/// `/proc/self/stat`, fields 14 and 15 at 100 ticks per second); `None` where that file cannot be
/// read or parsed. Measured speed is reported in CPU-s because wall time on a shared machine
/// says more about its load than about the code.
pub fn cpu_seconds() -> Option<f64> {
    stat_cpu_seconds("/proc/self/stat")
}

/// CPU seconds the calling thread has used so far, user + system (Linux
/// `/proc/thread-self/stat`, read as [`cpu_seconds`] reads the process's); `None` where that file
/// cannot be read or parsed. For per-task timing inside a rayon pool, where the process's clock
/// would also count the other workers.
pub fn thread_cpu_seconds() -> Option<f64> {
    stat_cpu_seconds("/proc/thread-self/stat")
}

/// User + system CPU seconds from a `/proc/…/stat` file (fields 14 and 15, 100 ticks per second).
fn stat_cpu_seconds(path: &str) -> Option<f64> {
    let stat = std::fs::read_to_string(path).ok()?;
    // The command name (field 2) is in parentheses and may hold spaces: count after the last ')'.
    let rest = &stat[stat.rfind(')')? + 1..];
    let mut fields = rest.split_whitespace().skip(11);
    let user: f64 = fields.next()?.parse().ok()?;
    let system: f64 = fields.next()?.parse().ok()?;
    Some((user + system) / 100.0)
}

#[cfg(test)]
mod tests {
    #[cfg(target_os = "linux")]
    #[test]
    fn cpu_seconds_grow_with_work() {
        let start = super::cpu_seconds().expect("/proc/self/stat parses on Linux");
        let mut x = 0.0_f64;
        let t0 = std::time::Instant::now();
        while t0.elapsed().as_secs_f64() < 0.05 {
            x = (x + 1.0).sqrt();
        }
        assert!(x.is_finite());
        let end = super::cpu_seconds().expect("readable a moment ago");
        assert!(
            end > 0.0 && end >= start && end - start < 10.0,
            "{start} -> {end}"
        );
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn the_thread_clock_is_part_of_the_process_clock() {
        let thread = super::thread_cpu_seconds().expect("/proc/thread-self/stat parses on Linux");
        let process = super::cpu_seconds().expect("/proc/self/stat parses on Linux");
        assert!(
            thread >= 0.0 && thread <= process + 0.01,
            "{thread} vs {process}"
        );
    }
}
