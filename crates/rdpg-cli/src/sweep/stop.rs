//! `rdpg sweep FILE --stop`: stops a running sweep from any shell, as Ctrl-C to its driver
//! would: each running trial's `rdpg train` gets one SIGTERM and saves its checkpoint, Tune keeps
//! its state, and a rerun of `rdpg sweep FILE` continues every unfinished trial. It leaves the
//! stop marker the driver watches (`stop.json` in the sweep's folder, the same marker a trial
//! stopped from outside leaves) and returns once the driver has exited, that is once every
//! running trial has saved. The driver names itself in `driver.json` while it runs.

use std::path::Path;
use std::time::Duration;

use anyhow::{bail, Result};

use super::Sweep;
use crate::rundir::{read_json, write_json};

/// What `rdpg sweep FILE --stop` writes to the stop marker; the driver prints it.
const BY: &str = "rdpg sweep --stop";

/// Stops the sweep's driver and waits until it has exited. A sweep that is not running is
/// said so, and is not an error (stopping is idempotent).
pub(super) fn stop(sweep: &Sweep, file: &Path) -> Result<()> {
    let name = &sweep.file.name;
    let Some(pid) = running_driver(sweep)? else {
        println!("sweep `{name}` is not running");
        return Ok(());
    };
    write_json(
        &sweep.root.join("stop.json"),
        &serde_json::json!({ "by": BY }),
    )?;
    eprintln!(
        "stopping sweep `{name}` (driver process {pid}): each running trial saves its \
         checkpoint first"
    );
    while driver_alive(pid, sweep)? {
        std::thread::sleep(Duration::from_millis(500));
    }
    println!(
        "sweep `{name}` stopped; `rdpg sweep {}` continues it",
        file.display()
    );
    Ok(())
}

/// The process id in `driver.json`, if that process is still this sweep's driver.
pub(super) fn running_driver(sweep: &Sweep) -> Result<Option<u32>> {
    let record = sweep.root.join("driver.json");
    if !record.exists() {
        return Ok(None);
    }
    let v: serde_json::Value = read_json(&record)?;
    let Some(pid) = v["pid"].as_u64().and_then(|p| u32::try_from(p).ok()) else {
        bail!("{}: no process id in it", record.display());
    };
    // A record left by a driver that died (or a machine that went away) names no driver.
    Ok(driver_alive(pid, sweep)?.then_some(pid))
}

/// Whether process `pid` is this sweep's driver: on Linux, its command line names the sweep's
/// `plan.json` as `rdpg sweep` hands it over (a reused process id does not); elsewhere on Unix,
/// whether the process exists.
fn driver_alive(pid: u32, sweep: &Sweep) -> Result<bool> {
    #[cfg(target_os = "linux")]
    {
        let plan = sweep.root.join("plan.json").display().to_string();
        Ok(std::fs::read(format!("/proc/{pid}/cmdline"))
            .is_ok_and(|cmd| String::from_utf8_lossy(&cmd).contains(&plan)))
    }
    #[cfg(all(unix, not(target_os = "linux")))]
    {
        let _ = sweep;
        let pid = nix::unistd::Pid::from_raw(pid as i32);
        Ok(nix::sys::signal::kill(pid, None).is_ok())
    }
    #[cfg(not(unix))]
    {
        let _ = (pid, sweep);
        bail!("`rdpg sweep --stop` needs a Unix system: stop the driver with Ctrl-C")
    }
}
