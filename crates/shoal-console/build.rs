//! Builds the web console (the Mission Management Tool's front end, `web/`) into `OUT_DIR`
//! and writes `web_assets.rs`, a table of its files embedded with `include_bytes!`, so the
//! station binary serves the console with nothing to install at run time.
//!
//! `npm ci` runs only when `web/node_modules` is missing or `package-lock.json` changed
//! since the last install (a stamp in `node_modules` records its hash); the Vite build runs
//! whenever cargo re-runs this script, which it does only when the sources listed below
//! change.

use std::fmt::Write as _;
use std::fs;
use std::io::ErrorKind;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, SystemTime};

const STAMP: &str = ".shoal-lock-hash";

fn main() {
    if let Err(e) = run() {
        eprintln!("\nshoal-console: cannot build the web console: {e}\n");
        std::process::exit(1);
    }
}

fn run() -> Result<(), String> {
    let manifest = std::env::var_os("CARGO_MANIFEST_DIR").ok_or("CARGO_MANIFEST_DIR is not set")?;
    let out = PathBuf::from(std::env::var_os("OUT_DIR").ok_or("OUT_DIR is not set")?);
    let web = Path::new(&manifest).join("web");
    for watched in [
        "src",
        "index.html",
        "package.json",
        "package-lock.json",
        "vite.config.js",
    ] {
        println!("cargo:rerun-if-changed={}", web.join(watched).display());
    }

    check_npm()?;
    // Concurrent builds (several target dirs, clippy beside a build) share node_modules.
    let _lock = Lock::take(&web.join(".build-lock"))?;
    install_if_needed(&web)?;
    let dist = out.join("web-dist");
    let vite = web.join("node_modules/vite/bin/vite.js");
    let status = Command::new("node")
        .arg(&vite)
        .args(["build", "--emptyOutDir", "--logLevel", "warn", "--outDir"])
        .arg(&dist)
        .current_dir(&web)
        .status()
        .map_err(|e| format!("cannot run node: {e}"))?;
    if !status.success() {
        return Err(format!(
            "the Vite build failed ({status}); see its output above"
        ));
    }
    write_table(&dist, &out.join("web_assets.rs"))
}

fn check_npm() -> Result<(), String> {
    match Command::new("npm").arg("--version").output() {
        Ok(o) if o.status.success() => Ok(()),
        Ok(o) => Err(format!(
            "`npm --version` failed ({}): install Node.js (v20.19 or later) and npm \
             (Debian: apt-get install nodejs npm)",
            o.status
        )),
        Err(e) if e.kind() == ErrorKind::NotFound => Err(
            "npm is not installed. Install Node.js (v20.19 or later) and npm to build the \
             console, e.g. on Debian: apt-get install nodejs npm"
                .into(),
        ),
        Err(e) => Err(format!("cannot run npm: {e}")),
    }
}

/// FNV-1a: only to notice that the lock file changed, not for security.
fn fnv1a(bytes: &[u8]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in bytes {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    format!("{h:016x}")
}

fn install_if_needed(web: &Path) -> Result<(), String> {
    let lock = fs::read(web.join("package-lock.json"))
        .map_err(|e| format!("cannot read web/package-lock.json: {e}"))?;
    let want = fnv1a(&lock);
    let stamp = web.join("node_modules").join(STAMP);
    if fs::read_to_string(&stamp).is_ok_and(|have| have.trim() == want) {
        return Ok(());
    }
    let status = Command::new("npm")
        .args([
            "ci",
            "--no-audit",
            "--no-fund",
            "--loglevel=error",
            "--include=dev",
        ])
        .current_dir(web)
        .status()
        .map_err(|e| format!("cannot run npm ci: {e}"))?;
    if !status.success() {
        return Err(format!(
            "`npm ci` in {} failed ({status}): it needs the npm registry once, to fill \
             web/node_modules",
            web.display()
        ));
    }
    fs::write(&stamp, want).map_err(|e| format!("cannot write {}: {e}", stamp.display()))
}

fn mime(path: &str) -> &'static str {
    match path.rsplit('.').next().unwrap_or("") {
        "html" => "text/html; charset=utf-8",
        "js" | "mjs" => "text/javascript; charset=utf-8",
        "css" => "text/css; charset=utf-8",
        "json" | "geojson" => "application/json",
        "svg" => "image/svg+xml",
        "png" => "image/png",
        "ico" => "image/x-icon",
        "woff2" => "font/woff2",
        "map" => "application/json",
        _ => "application/octet-stream",
    }
}

fn collect(dir: &Path, root: &Path, files: &mut Vec<(String, PathBuf)>) -> Result<(), String> {
    let entries = fs::read_dir(dir).map_err(|e| format!("cannot list {}: {e}", dir.display()))?;
    for entry in entries {
        let path = entry.map_err(|e| e.to_string())?.path();
        if path.is_dir() {
            collect(&path, root, files)?;
        } else {
            let rel = path
                .strip_prefix(root)
                .map_err(|e| e.to_string())?
                .to_string_lossy()
                .replace('\\', "/");
            files.push((format!("/{rel}"), path));
        }
    }
    Ok(())
}

fn write_table(dist: &Path, target: &Path) -> Result<(), String> {
    let mut files = Vec::new();
    collect(dist, dist, &mut files)?;
    files.sort();
    if !files.iter().any(|(p, _)| p == "/index.html") {
        return Err(format!(
            "the Vite build left no index.html in {}",
            dist.display()
        ));
    }
    let mut code = String::from(
        "/// Every file of the built console: (URL path, media type, contents).\n\
         pub(crate) static ASSETS: &[(&str, &str, &[u8])] = &[\n",
    );
    for (url, path) in &files {
        let abs = path.to_str().ok_or("non-UTF-8 path in the build output")?;
        let _ = writeln!(
            code,
            "    ({url:?}, {:?}, include_bytes!({abs:?})),",
            mime(url)
        );
    }
    code.push_str("];\n");
    fs::write(target, code).map_err(|e| format!("cannot write {}: {e}", target.display()))
}

/// A directory used as a lock across processes: creating a directory is atomic.
struct Lock(PathBuf);

impl Lock {
    fn take(path: &Path) -> Result<Self, String> {
        // A lock older than this was left by a build that died.
        const STALE: Duration = Duration::from_secs(20 * 60);
        const WAIT: Duration = Duration::from_secs(30 * 60);
        let start = SystemTime::now();
        loop {
            match fs::create_dir(path) {
                Ok(()) => return Ok(Self(path.to_path_buf())),
                Err(e) if e.kind() == ErrorKind::AlreadyExists => {
                    let age = fs::metadata(path)
                        .and_then(|m| m.modified())
                        .ok()
                        .and_then(|m| m.elapsed().ok());
                    if age.is_some_and(|a| a > STALE) {
                        let _ = fs::remove_dir(path);
                        continue;
                    }
                    if start.elapsed().is_ok_and(|w| w > WAIT) {
                        return Err(format!(
                            "another build has held {} for 30 minutes; remove it if no build runs",
                            path.display()
                        ));
                    }
                    std::thread::sleep(Duration::from_millis(500));
                }
                Err(e) => return Err(format!("cannot create {}: {e}", path.display())),
            }
        }
    }
}

impl Drop for Lock {
    fn drop(&mut self) {
        let _ = fs::remove_dir(&self.0);
    }
}
