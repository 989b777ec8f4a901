//! The host's facts, as summaries and memory checks name them.

/// This host in words: architecture, CPU model and count, memory, e.g. "x86_64, 2 CPUs (AMD
/// EPYC 7B13), 24 GiB RAM". Training devices other than the CPU are in each run's config.
pub fn machine_description() -> String {
    let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let model = cpuinfo
        .lines()
        .find_map(|l| l.strip_prefix("model name"))
        .and_then(|l| l.split_once(':'))
        .map(|(_, m)| m.trim().to_string());
    let cpus = std::thread::available_parallelism().map_or(0, |n| n.get());
    let mem_gib = meminfo_bytes("MemTotal").map(|b| b as f64 / (1u64 << 30) as f64);
    let mut s = format!("{}, {cpus} CPUs", std::env::consts::ARCH);
    if let Some(m) = model {
        s += &format!(" ({m})");
    }
    if let Some(g) = mem_gib {
        s += &format!(", {g:.0} GiB RAM");
    }
    s
}

/// A `/proc/meminfo` entry (e.g. `MemTotal`, `MemAvailable`) in bytes; `None` where there
/// is no such file or entry.
pub fn meminfo_bytes(key: &str) -> Option<u64> {
    let m = std::fs::read_to_string("/proc/meminfo").ok()?;
    let kb = m
        .lines()
        .find_map(|l| l.strip_prefix(key)?.strip_prefix(':'))?;
    kb.trim()
        .trim_end_matches("kB")
        .trim()
        .parse::<u64>()
        .ok()
        .map(|kb| kb * 1024)
}
