//! Writing a file whole or not at all, without writing through links.
//!
//! [`write_replacing`] writes the bytes to a new temporary file in the target's folder, opened with
//! `create_new` (`O_CREAT | O_EXCL`: it fails on any existing name, a link included, instead of following
//! it, and the next name is tried), flushes it to the disk, and renames it over the target. A rename
//! replaces the directory entry itself: a link at the target's name is replaced by the file, and what it
//! pointed to is left alone. A reader sees either the old file or the new one, and an interrupted write
//! leaves the old one. On any error the temporary is removed. Temporary names are `.<name>.<pid>.<n>.tmp`,
//! hidden, and unique within the process by a counter.
use crate::error::{MapError, Result};
use std::ffi::OsString;
use std::fs::{File, OpenOptions};
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Names tried before giving up: each is only taken by another file of the same process id and counter,
/// i.e. left by a process killed mid-write that had this one's id.
const ATTEMPTS: u64 = 64;

/// Counter that makes temporary names unique within the process.
static NEXT_TEMPORARY: AtomicU64 = AtomicU64::new(0);

/// Write `bytes` to `path` as described in the module docs. Errors name `path` and give the system's
/// reason.
pub(crate) fn write_replacing(path: &Path, bytes: &[u8]) -> Result<()> {
    let io_error = |source| MapError::Io {
        path: path.display().to_string(),
        source,
    };
    let name = path.file_name().ok_or_else(|| {
        io_error(io::Error::new(
            io::ErrorKind::InvalidInput,
            "the path does not name a file",
        ))
    })?;
    let folder = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let (temporary_path, file) = create_temporary(folder, name).map_err(io_error)?;
    let written = write_and_sync(file, bytes).and_then(|()| std::fs::rename(&temporary_path, path));
    if let Err(source) = written {
        // The error to report is the write's; a temporary that cannot be removed is no worse.
        let _ = std::fs::remove_file(&temporary_path);
        return Err(io_error(source));
    }
    Ok(())
}

/// A new file in `folder`, under a name no file had.
fn create_temporary(folder: &Path, name: &std::ffi::OsStr) -> io::Result<(PathBuf, File)> {
    let pid = std::process::id();
    let mut last_error = None;
    for _ in 0..ATTEMPTS {
        let n = NEXT_TEMPORARY.fetch_add(1, Ordering::Relaxed);
        let mut temporary = OsString::from(".");
        temporary.push(name);
        temporary.push(format!(".{pid}.{n}.tmp"));
        let temporary_path = folder.join(temporary);
        match OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&temporary_path)
        {
            Ok(file) => return Ok((temporary_path, file)),
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => last_error = Some(e),
            Err(e) => return Err(e),
        }
    }
    Err(last_error.unwrap_or_else(|| io::Error::other("no temporary name was free")))
}

fn write_and_sync(mut file: File, bytes: &[u8]) -> io::Result<()> {
    file.write_all(bytes)?;
    file.flush()?;
    // On the disk before the rename makes it the target: a crash then leaves the old file or the new.
    file.sync_all()
}

#[cfg(test)]
pub(crate) mod test_support {
    use std::path::PathBuf;
    use std::sync::atomic::{AtomicU64, Ordering};

    /// A fresh empty folder under the system's temporary one, removed when dropped.
    pub(crate) struct Scratch(pub PathBuf);

    impl Scratch {
        pub fn new(tag: &str) -> Self {
            static N: AtomicU64 = AtomicU64::new(0);
            let dir = std::env::temp_dir().join(format!(
                "hippo_map_{tag}_{}_{}",
                std::process::id(),
                N.fetch_add(1, Ordering::Relaxed)
            ));
            let _ = std::fs::remove_dir_all(&dir);
            std::fs::create_dir_all(&dir).unwrap();
            Self(dir)
        }

        pub fn names(&self) -> Vec<String> {
            let mut names: Vec<String> = std::fs::read_dir(&self.0)
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect();
            names.sort();
            names
        }
    }

    impl Drop for Scratch {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::test_support::Scratch;
    use super::*;

    #[test]
    fn writes_and_replaces_leaving_no_temporary() {
        let dir = Scratch::new("replace");
        let target = dir.0.join("out.txt");
        write_replacing(&target, b"first").unwrap();
        write_replacing(&target, b"second").unwrap();
        assert_eq!(std::fs::read(&target).unwrap(), b"second");
        assert_eq!(dir.names(), ["out.txt"]);
    }

    #[test]
    fn a_missing_folder_is_an_error_naming_the_target() {
        let dir = Scratch::new("missing");
        let target = dir.0.join("no_such_folder").join("out.txt");
        let err = write_replacing(&target, b"x").unwrap_err();
        let message = err.to_string();
        assert!(message.contains(&target.display().to_string()), "{message}");
        assert!(message.contains("No such file or directory"), "{message}");
        assert!(dir.names().is_empty());
    }

    /// The rename fails (the target is a folder) after the temporary was written: it is removed.
    #[test]
    fn a_failed_rename_removes_the_temporary() {
        let dir = Scratch::new("rename");
        let target = dir.0.join("out.txt");
        std::fs::create_dir(&target).unwrap();
        let err = write_replacing(&target, b"x").unwrap_err();
        assert!(
            err.to_string().contains(&target.display().to_string()),
            "{err}"
        );
        assert_eq!(dir.names(), ["out.txt"]);
        assert!(target.is_dir());
    }

    #[cfg(unix)]
    #[test]
    fn a_link_at_the_target_is_replaced_and_what_it_points_to_is_untouched() {
        let dir = Scratch::new("link");
        let victim = dir.0.join("victim");
        std::fs::write(&victim, b"precious").unwrap();
        let target = dir.0.join("out.txt");
        std::os::unix::fs::symlink(&victim, &target).unwrap();
        write_replacing(&target, b"new").unwrap();
        assert_eq!(std::fs::read(&victim).unwrap(), b"precious");
        assert!(std::fs::symlink_metadata(&target).unwrap().is_file());
        assert_eq!(std::fs::read(&target).unwrap(), b"new");
    }
}
