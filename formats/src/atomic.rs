//! Atomic file writing: the file appears complete or not at all, so a failed or interrupted
//! run never leaves a half-written image behind for a compositor to pick up.

use std::io::Seek;
use std::path::Path;

use crate::error::{Error, Result};

/// Writes through `write` into a temporary file in `path`'s folder, flushes it to disk and
/// renames it into place. The file gets the permissions any newly created file gets (0666
/// less the process's umask), not a temporary file's private 0600, so a render-farm service or
/// another user can read it.
pub fn write_atomically<F>(path: &Path, write: F) -> Result<()>
where
    F: FnOnce(&mut std::fs::File) -> Result<()>,
{
    let io = |source| Error::io(path, source);
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => std::path::PathBuf::from("."),
    };
    let mut builder = tempfile::Builder::new();
    builder.prefix(".spreadlet-tmp-");
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        // The mode given at creation is reduced by the umask, as for any new file.
        builder.permissions(std::fs::Permissions::from_mode(0o666));
    }
    let mut tmp = builder.tempfile_in(&dir).map_err(io)?;
    write(tmp.as_file_mut())?;
    tmp.as_file_mut().rewind().map_err(io)?;
    tmp.as_file().sync_all().map_err(io)?;
    tmp.persist(path).map_err(|e| io(e.error))?;
    Ok(())
}

/// [`write_atomically`] of a byte string.
pub fn write_bytes_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomically(path, |file| {
        use std::io::Write;
        file.write_all(bytes).map_err(|e| Error::io(path, e))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_failed_write_leaves_nothing() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("out.exr");
        let result = write_atomically(&path, |_| {
            Err(Error::Layout {
                path: path.clone(),
                message: "refused".into(),
            })
        });
        assert!(result.is_err());
        let left: Vec<_> = std::fs::read_dir(dir.path()).expect("list").collect();
        assert!(left.is_empty(), "files left behind: {left:?}");
    }

    #[cfg(unix)]
    #[test]
    fn outputs_get_the_mode_of_any_new_file() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().expect("temp dir");
        // What the umask makes of 0666: the mode of a file created the ordinary way.
        let plain = dir.path().join("plain");
        std::fs::write(&plain, b"x").expect("write");
        let expected = std::fs::metadata(&plain)
            .expect("stat")
            .permissions()
            .mode()
            & 0o777;
        let path = dir.path().join("atomic");
        write_bytes_atomically(&path, b"x").expect("write");
        let mode = std::fs::metadata(&path).expect("stat").permissions().mode() & 0o777;
        assert_eq!(
            mode, expected,
            "atomic output {mode:o}, plain file {expected:o}"
        );
    }
}
