//! Peak resident memory of this process over a stretch of work, from Linux's
//! `/proc/self`: the peak is reset before a stage (`clear_refs` 5, Linux 4.0
//! and later) and read after it (`VmHWM`). Elsewhere, or where `/proc` is
//! not writable, there is no figure. And the memory still available, which
//! bounds how many models run side by side.

/// Starts a new peak at the current resident memory.
pub fn reset_peak() {
    // Best effort: without it the figure is the peak since the process started.
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

/// The peak resident memory since the last [`reset_peak`] (or the start), MiB.
pub fn peak_rss_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find_map(|l| l.strip_prefix("VmHWM:"))?;
    let kib: f64 = line.trim().strip_suffix("kB")?.trim().parse().ok()?;
    Some(kib / 1024.0)
}

/// The memory available for new work (`MemAvailable`), MiB, if known.
pub fn available_mib() -> Option<f64> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = info.lines().find_map(|l| l.strip_prefix("MemAvailable:"))?;
    let kib: f64 = line.trim().strip_suffix("kB")?.trim().parse().ok()?;
    Some(kib / 1024.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_peak_is_reset_and_follows_an_allocation() {
        // Other tests run on other threads of this process and allocate, free
        // and reset the peak too: the margins are wide for that.
        reset_peak();
        let Some(before) = peak_rss_mib() else { return }; // not Linux
        let touched = std::hint::black_box(vec![1u8; 128 << 20]);
        let during = peak_rss_mib().unwrap();
        assert!(during >= before + 96.0, "{before} -> {during} MiB after touching 128 MiB");
        drop(touched);
        reset_peak();
        let after = peak_rss_mib().unwrap();
        assert!(after < during - 96.0, "{during} -> {after} MiB after the reset");
    }
}
