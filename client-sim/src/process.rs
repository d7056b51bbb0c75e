//! Real processes for end-to-end tests and deployment benchmarks: the binaries of this build
//! and a zenohd router, each killed when dropped, with its output in a log file.

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A binary of this build (`impact-server`, `impact-sim`): beside the running executable, or
/// one folder up from a test's `deps/`.
pub fn binary(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("the running executable");
    let dir = exe.parent().expect("its folder");
    let found = [dir.join(name), dir.parent().map_or_else(PathBuf::new, |d| d.join(name))];
    found.iter().find(|p| p.exists()).cloned().unwrap_or_else(|| {
        panic!("{name} is missing beside {}: build it first (cargo build --workspace --bins)", exe.display())
    })
}

/// The zenohd 1.10.2 binary, installed by `scripts/zenohd` on first use (cargo install, cached).
pub fn zenohd() -> PathBuf {
    let script = repo().join("scripts/zenohd");
    let out = Command::new("bash").arg(&script).arg("path").stderr(Stdio::inherit()).output().expect("scripts/zenohd");
    assert!(out.status.success(), "scripts/zenohd path failed: zenohd 1.10.2 could not be installed");
    PathBuf::from(String::from_utf8_lossy(&out.stdout).trim())
}

/// The repository: the one the working directory is in, else the one this crate was built from.
fn repo() -> PathBuf {
    impact_core::scene::checkout()
}

/// The repository's router configuration.
pub fn router_config() -> PathBuf {
    repo().join("deploy/zenohd.json5")
}

/// Resident memory of a process, MiB (0 when it is gone).
pub fn rss_mib(pid: u32) -> f64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    let kb = status.lines().find_map(|l| l.strip_prefix("VmRSS:")).and_then(|v| v.split_whitespace().next());
    kb.and_then(|k| k.parse::<f64>().ok()).map_or(0.0, |k| k / 1024.0)
}

/// A child process with its stdout and stderr in a log file; killed (after SIGCONT, in case it
/// was stopped) when dropped.
#[derive(Debug)]
pub struct Proc {
    /// The process.
    pub child: Child,
    /// Its log.
    pub log: PathBuf,
}

impl Proc {
    /// Starts `cmd` with stdout and stderr going to a fresh log file named after `name` (kept
    /// after the process ends when `IMPACT_KEEP_LOGS` is set).
    pub fn spawn(name: &str, mut cmd: Command) -> Proc {
        let log = std::env::temp_dir().join(format!("impact-{name}-{}.log", std::process::id()));
        let file = std::fs::File::create(&log).expect("log file");
        let err = file.try_clone().expect("log file");
        let child = cmd
            .stdout(file)
            .stderr(err)
            .stdin(Stdio::null())
            .spawn()
            .unwrap_or_else(|e| panic!("starting {name}: {e}"));
        Proc { child, log }
    }

    /// A router listening on `listen`, meshed with the routers at `connect`.
    pub fn router(name: &str, listen: &str, connect: &[String]) -> Proc {
        let mut cmd = Command::new(zenohd());
        cmd.arg("--config").arg(router_config()).args(["--listen", listen]);
        for c in connect {
            cmd.args(["--connect", c]);
        }
        cmd.env("RUST_LOG", std::env::var("IMPACT_ROUTER_LOG").unwrap_or_else(|_| "warn".into()));
        Proc::spawn(name, cmd)
    }

    /// The process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// What it printed so far.
    pub fn output(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// Waits up to `timeout` for its output to contain `text`.
    pub fn wait_for_output(&self, text: &str, timeout: Duration) -> bool {
        let end = Instant::now() + timeout;
        while Instant::now() < end {
            if self.output().contains(text) {
                return true;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        false
    }

    /// Sends a signal (`INT`, `KILL`, `STOP`, `CONT`).
    pub fn signal(&self, sig: &str) {
        let _ = Command::new("kill").arg(format!("-{sig}")).arg(self.pid().to_string()).stderr(Stdio::null()).status();
    }

    /// Asks it to stop (SIGINT) and waits at most 10 s for its exit status.
    pub fn stop(&mut self) -> Option<std::process::ExitStatus> {
        self.signal("INT");
        self.wait(Duration::from_secs(10))
    }

    /// Waits at most `timeout` for it to exit.
    pub fn wait(&mut self, timeout: Duration) -> Option<std::process::ExitStatus> {
        let end = Instant::now() + timeout;
        while Instant::now() < end {
            if let Ok(Some(status)) = self.child.try_wait() {
                return Some(status);
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        None
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        self.signal("CONT");
        let _ = self.child.kill();
        let _ = self.child.wait();
        if std::env::var_os("IMPACT_KEEP_LOGS").is_none() {
            let _ = std::fs::remove_file(&self.log);
        }
    }
}
