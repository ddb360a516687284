//! Reading and writing key-store files with the permissions secrets need, and load errors
//! that name the file and the problem in one line.

use std::fs::{self, OpenOptions};
use std::io::{self, Write};
use std::os::unix::fs::{DirBuilderExt, OpenOptionsExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use tracing::warn;
use zeroize::Zeroizing;

/// Mode of private keys and symmetric keys: owner read/write only.
pub const SECRET_FILE_MODE: u32 = 0o600;
/// Mode of certificates and the revocation list: public, but only the owner writes.
pub const PUBLIC_FILE_MODE: u32 = 0o644;
/// Mode of the key-store directory: owner only.
pub const DIR_MODE: u32 = 0o700;

/// What is wrong with one file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FileProblem {
    /// The file does not exist.
    #[error("missing")]
    Missing,
    /// The file exists but could not be read.
    #[error("unreadable: {0}")]
    Unreadable(io::Error),
    /// The file could not be written.
    #[error("could not be written: {0}")]
    Unwritable(io::Error),
    /// A secret that group or others may read or write.
    #[error(
        "holds a secret but has mode {mode:04o} (group/others have access); refusing it: run `chmod 600` on it"
    )]
    TooOpen {
        /// The file's permission bits.
        mode: u32,
    },
    /// The content is not a PEM block.
    #[error("not PEM: {0}")]
    NotPem(String),
    /// A PEM block of another kind than expected.
    #[error("holds a PEM block labelled {found:?}, expected {expected:?}")]
    WrongLabel {
        /// The label this file must have.
        expected: &'static str,
        /// The label it has.
        found: String,
    },
    /// The certificate could not be parsed or is not one Shoal issues.
    #[error("not a usable certificate: {0}")]
    BadCertificate(String),
    /// The private or symmetric key could not be decoded.
    #[error("not a usable key: {0}")]
    BadKey(String),
    /// The certificate (or CA) is past its validity period.
    #[error("expired on {0}")]
    Expired(String),
    /// The certificate is not valid yet.
    #[error("not valid before {0}")]
    NotYetValid(String),
    /// The signature does not verify with the station CA's key.
    #[error("its signature does not verify against the station CA")]
    BadSignature,
    /// The private key does not belong to the certificate next to it.
    #[error("the private key does not match the certificate {0}")]
    KeyMismatch(PathBuf),
    /// Anything else, explained.
    #[error("{0}")]
    Invalid(String),
}

/// A file and what is wrong with it; displays as `<path>: <problem>`.
#[derive(Debug, thiserror::Error)]
#[error("{}: {problem}", path.display())]
pub struct FileError {
    /// The file.
    pub path: PathBuf,
    /// The problem.
    pub problem: FileProblem,
}

impl FileError {
    /// A problem with `path`.
    pub fn new(path: impl Into<PathBuf>, problem: FileProblem) -> Self {
        Self {
            path: path.into(),
            problem,
        }
    }
}

fn read_error(path: &Path, e: io::Error) -> FileError {
    let problem = if e.kind() == io::ErrorKind::NotFound {
        FileProblem::Missing
    } else {
        FileProblem::Unreadable(e)
    };
    FileError::new(path, problem)
}

/// Reads a public file (certificate, revocation list) as text.
pub fn read_public(path: &Path) -> Result<String, FileError> {
    let bytes = fs::read(path).map_err(|e| read_error(path, e))?;
    String::from_utf8(bytes)
        .map_err(|_| FileError::new(path, FileProblem::NotPem("not UTF-8 text".into())))
}

/// Reads a secret file, refusing it when group or others have any access to it.
///
/// Refusing rather than warning follows OpenSSH: a key others could read must be assumed
/// copied, and silently using it would hide that.
pub fn read_secret(path: &Path) -> Result<Zeroizing<String>, FileError> {
    let meta = fs::metadata(path).map_err(|e| read_error(path, e))?;
    let mode = meta.permissions().mode() & 0o777;
    if mode & 0o077 != 0 {
        return Err(FileError::new(path, FileProblem::TooOpen { mode }));
    }
    let bytes = Zeroizing::new(fs::read(path).map_err(|e| read_error(path, e))?);
    match std::str::from_utf8(&bytes) {
        Ok(s) => Ok(Zeroizing::new(s.to_owned())),
        Err(_) => Err(FileError::new(
            path,
            FileProblem::NotPem("not UTF-8 text".into()),
        )),
    }
}

/// Parses one PEM block with the expected label.
pub fn parse_pem(path: &Path, text: &str, label: &'static str) -> Result<pem::Pem, FileError> {
    let block =
        pem::parse(text).map_err(|e| FileError::new(path, FileProblem::NotPem(e.to_string())))?;
    if block.tag() != label {
        return Err(FileError::new(
            path,
            FileProblem::WrongLabel {
                expected: label,
                found: block.tag().to_owned(),
            },
        ));
    }
    Ok(block)
}

/// Warns when a key-store directory is open to group or others; its files are still
/// checked one by one, so this is advice, not a refusal.
pub fn check_dir(path: &Path) -> Result<(), FileError> {
    let meta = fs::metadata(path).map_err(|e| read_error(path, e))?;
    if !meta.is_dir() {
        return Err(FileError::new(
            path,
            FileProblem::Invalid("is not a directory".into()),
        ));
    }
    let mode = meta.permissions().mode() & 0o777;
    if mode & 0o077 != 0 {
        warn!(
            dir = %path.display(),
            mode = format_args!("{mode:04o}"),
            "key-store directory is accessible to group/others; expected 0700"
        );
    }
    Ok(())
}

/// Creates a directory (and parents) with mode 0700, or tightens an existing one to 0700.
pub fn create_private_dir(path: &Path) -> Result<(), FileError> {
    let unwritable = |e| FileError::new(path, FileProblem::Unwritable(e));
    fs::DirBuilder::new()
        .recursive(true)
        .mode(DIR_MODE)
        .create(path)
        .map_err(unwritable)?;
    // `mode` applies only to directories it created, and the umask may have narrowed it.
    fs::set_permissions(path, fs::Permissions::from_mode(DIR_MODE)).map_err(unwritable)
}

/// Writes a secret file with mode 0600 (see [`write_file`]).
pub fn write_secret(path: &Path, bytes: &[u8]) -> Result<(), FileError> {
    write_file(path, bytes, SECRET_FILE_MODE)
}

/// Writes a public file with mode 0644 (see [`write_file`]).
pub fn write_public(path: &Path, bytes: &[u8]) -> Result<(), FileError> {
    write_file(path, bytes, PUBLIC_FILE_MODE)
}

/// Writes `bytes` to `path` atomically: a temporary file created with `mode` in the same
/// directory, synced, then renamed over the target.
///
/// Creating with the final mode (rather than chmod after writing) means a secret is never
/// readable by others, not even for an instant; the rename means a crash leaves either the
/// old file or the new one, never half of one (which matters for the revocation list).
pub fn write_file(path: &Path, bytes: &[u8], mode: u32) -> Result<(), FileError> {
    let unwritable = |e| FileError::new(path, FileProblem::Unwritable(e));
    let file_name = path
        .file_name()
        .ok_or_else(|| unwritable(io::Error::other("no file name")))?;
    // Unique per process and per call, so two writers never share a temporary file.
    static NEXT: AtomicU64 = AtomicU64::new(0);
    let mut tmp_name = file_name.to_os_string();
    tmp_name.push(format!(
        ".tmp-{}-{}",
        std::process::id(),
        NEXT.fetch_add(1, Ordering::Relaxed)
    ));
    let tmp = path.with_file_name(tmp_name);
    let result = (|| {
        let mut f = OpenOptions::new()
            .write(true)
            .create_new(true)
            .mode(mode)
            .open(&tmp)?;
        // The umask may have removed bits we asked for (never added any): set them exactly.
        f.set_permissions(fs::Permissions::from_mode(mode))?;
        f.write_all(bytes)?;
        f.sync_all()?;
        fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result.map_err(unwritable)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mode_of(p: &Path) -> u32 {
        fs::metadata(p).unwrap().permissions().mode() & 0o777
    }

    #[test]
    fn secrets_are_written_0600_and_public_files_0644() {
        let dir = tempfile::tempdir().unwrap();
        let s = dir.path().join("k");
        write_secret(&s, b"secret").unwrap();
        assert_eq!(mode_of(&s), 0o600);
        let p = dir.path().join("c");
        write_public(&p, b"cert").unwrap();
        assert_eq!(mode_of(&p), 0o644);
        // Overwriting keeps the mode and replaces the content.
        write_secret(&s, b"other").unwrap();
        assert_eq!(*read_secret(&s).unwrap(), "other");
    }

    #[test]
    fn open_secrets_are_refused_with_the_mode_in_the_message() {
        let dir = tempfile::tempdir().unwrap();
        let s = dir.path().join("k");
        write_secret(&s, b"secret").unwrap();
        fs::set_permissions(&s, fs::Permissions::from_mode(0o640)).unwrap();
        let err = read_secret(&s).unwrap_err();
        assert!(matches!(err.problem, FileProblem::TooOpen { mode: 0o640 }));
        let msg = err.to_string();
        assert!(msg.starts_with(&s.display().to_string()), "{msg}");
        assert!(msg.contains("0640"), "{msg}");
    }

    #[test]
    fn missing_files_say_missing() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("nope.crt");
        let err = read_public(&p).unwrap_err();
        assert!(matches!(err.problem, FileProblem::Missing));
        assert_eq!(err.to_string(), format!("{}: missing", p.display()));
    }

    #[test]
    fn private_dirs_are_0700_even_when_they_existed() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path().join("store");
        fs::create_dir(&d).unwrap();
        fs::set_permissions(&d, fs::Permissions::from_mode(0o755)).unwrap();
        create_private_dir(&d).unwrap();
        assert_eq!(mode_of(&d), 0o700);
    }

    #[test]
    fn wrong_pem_label_is_named() {
        let text = pem::encode(&pem::Pem::new("CERTIFICATE", vec![1, 2, 3]));
        let err = parse_pem(Path::new("x.key"), &text, "PRIVATE KEY").unwrap_err();
        assert!(err.to_string().contains("\"CERTIFICATE\""), "{err}");
        let err = parse_pem(Path::new("x.key"), "hello", "PRIVATE KEY").unwrap_err();
        assert!(matches!(err.problem, FileProblem::NotPem(_)));
    }
}
