//! Runs COLMAP's command-line steps: finds the binary (`--colmap` or `PATH`), runs one step with its arguments,
//! keeps its output as `<workspace>/<step>.log`, and names the step and the log when it fails.

use std::path::{Path, PathBuf};
use std::process::Command;

use super::SfmError;

/// The apt line for Debian 12 / Ubuntu (COLMAP 3.8 there; no CUDA, which msnerf does not need).
pub const INSTALL_HINT: &str = "install COLMAP with `sudo apt-get install colmap` (Debian 12 / Ubuntu; \
tools/setup-debian.sh does it) or give its binary with --colmap PATH";

/// A located COLMAP binary and its version line.
#[derive(Debug, Clone)]
pub struct Colmap {
    pub binary: PathBuf,
    pub version: String,
}

impl Colmap {
    /// `given` (a path) or `colmap` on `PATH`; runs `colmap help` to check it starts.
    pub fn find(given: Option<&Path>) -> Result<Colmap, SfmError> {
        let binary = match given {
            Some(p) if p.is_file() => p.to_path_buf(),
            Some(p) => {
                return Err(SfmError::ColmapMissing(format!("--colmap {}: no such file; {INSTALL_HINT}", p.display())))
            }
            None => std::env::var_os("PATH")
                .and_then(|paths| std::env::split_paths(&paths).map(|d| d.join("colmap")).find(|p| p.is_file()))
                .ok_or_else(|| SfmError::ColmapMissing(format!("COLMAP not found on PATH: {INSTALL_HINT}")))?,
        };
        let out = Command::new(&binary)
            .arg("help")
            .output()
            .map_err(|e| SfmError::ColmapMissing(format!("{}: cannot run ({e}); {INSTALL_HINT}", binary.display())))?;
        let text = String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
        let version =
            text.lines().find(|l| l.contains("COLMAP")).unwrap_or("COLMAP (version unknown)").trim().to_string();
        Ok(Colmap { binary, version })
    }

    /// Runs `colmap <step> <args>`, its output streamed into `workspace/<step>.log` (follow it with `tail -f`);
    /// returns the seconds it took.
    pub fn step(&self, workspace: &Path, step: &str, args: &[String]) -> Result<f64, SfmError> {
        let log = workspace.join(format!("{step}.log"));
        let io_err = |e: std::io::Error| SfmError::Dataset { path: log.clone(), reason: e.to_string() };
        let mut file = std::fs::File::create(&log).map_err(io_err)?;
        {
            use std::io::Write;
            writeln!(file, "$ {} {step} {}", self.binary.display(), args.join(" ")).map_err(io_err)?;
        }
        let err_file = file.try_clone().map_err(io_err)?;
        log::info!("COLMAP {step} (log: {})", log.display());
        let t0 = std::time::Instant::now();
        let status = Command::new(&self.binary)
            .arg(step)
            .args(args)
            .env("QT_QPA_PLATFORM", "offscreen")
            .stdout(file)
            .stderr(err_file)
            .status()
            .map_err(|e| SfmError::Step {
                step: step.into(),
                reason: format!("cannot start {}: {e}", self.binary.display()),
                log: log.clone(),
            })?;
        if !status.success() {
            let text = std::fs::read_to_string(&log).unwrap_or_default();
            let last: Vec<&str> = text.lines().rev().filter(|l| !l.trim().is_empty()).take(3).collect();
            let last: Vec<&str> = last.into_iter().rev().collect();
            return Err(SfmError::Step { step: step.into(), reason: format!("{status}: {}", last.join(" | ")), log });
        }
        Ok(t0.elapsed().as_secs_f64())
    }
}
