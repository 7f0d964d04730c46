//! The USD reader in a child process. A corrupt .usdc can make the `openusd` crate ask
//! for an absurd allocation, which aborts the process (allocation failure is not a
//! panic). `ppb` therefore parses every stage first in a child (`ppb __usd-probe`, with
//! its address space capped so a merely huge allocation fails fast too) and only then in
//! the process that renders; a child that dies becomes one clean error line.
use std::path::Path;
use std::process::{Command, Stdio};

use ppb::error::{Error, Result};

/// The probe `ppb::scene::usd` runs before parsing a stage in this process.
pub fn probe_in_child(path: &Path, frame: Option<u32>) -> Result<()> {
    let exe = std::env::current_exe()
        .map_err(|e| Error::Other(format!("finding ppb to check {}: {e}", path.display())))?;
    let mut cmd = Command::new(exe);
    cmd.arg("__usd-probe").arg(path);
    if let Some(f) = frame {
        cmd.args(["--frame", &f.to_string()]);
    }
    let out = cmd
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .output()
        .map_err(|e| Error::Other(format!("starting the USD check of {}: {e}", path.display())))?;
    if out.status.success() {
        return Ok(());
    }
    let stderr = String::from_utf8_lossy(&out.stderr);
    // The child's own error line, when it lived to print one.
    if out.status.code() == Some(2) {
        if let Some(line) = stderr.lines().rev().find_map(|l| l.strip_prefix("error: ")) {
            return Err(Error::Other(line.to_string()));
        }
    }
    Err(Error::format(
        path,
        format!(
            "the USD reader could not parse this stage (it {}; a corrupt .usdc?)",
            describe(&out.status)
        ),
    ))
}

#[cfg(unix)]
fn describe(status: &std::process::ExitStatus) -> String {
    use std::os::unix::process::ExitStatusExt;
    match status.signal() {
        Some(libc::SIGABRT) => "aborted".into(),
        Some(libc::SIGKILL) => "was killed, out of memory".into(),
        Some(s) => format!("died of signal {s}"),
        None => format!("exited with {status}"),
    }
}

#[cfg(not(unix))]
fn describe(status: &std::process::ExitStatus) -> String {
    format!("exited with {status}")
}

/// `ppb __usd-probe PATH`: parses the stage with the address space capped at half the
/// physical memory; exits 0, or 2 with the error on stderr (or dies).
pub fn usd_probe(path: &Path, frame: Option<u32>) -> anyhow::Result<std::process::ExitCode> {
    cap_address_space();
    ppb::scene::usd::probe_usd(path, frame)?;
    Ok(std::process::ExitCode::SUCCESS)
}

#[cfg(unix)]
fn cap_address_space() {
    // SAFETY: sysconf and setrlimit have no preconditions; a failure leaves no cap.
    unsafe {
        let pages = libc::sysconf(libc::_SC_PHYS_PAGES);
        let size = libc::sysconf(libc::_SC_PAGESIZE);
        if pages > 0 && size > 0 {
            let cap = (pages as u64 * size as u64 / 2) as libc::rlim_t;
            let lim = libc::rlimit {
                rlim_cur: cap,
                rlim_max: cap,
            };
            libc::setrlimit(libc::RLIMIT_AS, &lim);
        }
    }
}

#[cfg(not(unix))]
fn cap_address_space() {}
