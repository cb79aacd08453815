//! The process's resident memory, read from `/proc/self/status` (Linux), in mebibytes.
//!
//! One unit for memory across the crate: MiB (2^20 bytes), in names (`_mib`) and labels.

/// Bytes per mebibyte.
pub const BYTES_PER_MIB: f64 = 1024.0 * 1024.0;
/// Kibibytes per mebibyte (`/proc` reports kB meaning KiB).
pub const KIB_PER_MIB: f64 = 1024.0;
/// Value written to `/proc/self/clear_refs` to reset the peak resident set size.
const CLEAR_REFS_RESET_PEAK: &str = "5";

/// Current resident set size (`VmRSS`) in MiB, when `/proc` has it.
pub fn resident_mib() -> Option<f64> {
    proc_status_kib("VmRSS:").map(|kib| kib / KIB_PER_MIB)
}

/// Peak resident set size (`VmHWM`) in MiB, when `/proc` has it.
pub fn peak_resident_mib() -> Option<f64> {
    proc_status_kib("VmHWM:").map(|kib| kib / KIB_PER_MIB)
}

/// Resets the peak resident set size (Linux 4.0+); false where that is not possible.
pub fn reset_peak_resident() -> bool {
    std::fs::write("/proc/self/clear_refs", CLEAR_REFS_RESET_PEAK).is_ok()
}

/// The value in KiB (`/proc` writes "kB") of the field `key` (e.g. `"VmRSS:"`) in the text
/// of a `/proc/<pid>/status` file.
pub fn status_field_kib(status: &str, key: &str) -> Option<f64> {
    status
        .lines()
        .find_map(|l| l.strip_prefix(key))
        .and_then(|rest| rest.trim().trim_end_matches("kB").trim().parse().ok())
}

/// Resident set size in MiB of the process `pid`, when `/proc` has it.
pub fn resident_mib_of(pid: u32) -> Option<f64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    status_field_kib(&status, "VmRSS:").map(|kib| kib / KIB_PER_MIB)
}

/// Memory the kernel could give this process without swapping (`MemAvailable` of
/// `/proc/meminfo`), in MiB, when `/proc` has it.
pub fn available_mib() -> Option<f64> {
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok()?;
    status_field_kib(&meminfo, "MemAvailable:").map(|kib| kib / KIB_PER_MIB)
}

fn proc_status_kib(key: &str) -> Option<f64> {
    status_field_kib(&std::fs::read_to_string("/proc/self/status").ok()?, key)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_kib_fields_of_a_status_text() {
        let status = "Name:\tmode360\nVmHWM:\t  204800 kB\nVmRSS:\t   1024 kB\n";
        assert_eq!(status_field_kib(status, "VmHWM:"), Some(204800.0));
        assert_eq!(status_field_kib(status, "VmRSS:"), Some(1024.0));
        assert_eq!(status_field_kib(status, "VmSwap:"), None);
    }

    #[test]
    fn this_process_has_a_resident_set() {
        let rss = resident_mib().expect("Linux /proc");
        let peak = peak_resident_mib().expect("Linux /proc");
        assert!(rss > 0.1 && peak >= rss, "rss {rss} MiB, peak {peak} MiB");
        let own = resident_mib_of(std::process::id()).expect("own pid");
        assert!(own > 0.1);
    }
}
