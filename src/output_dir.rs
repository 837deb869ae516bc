//! The output folder, written atomically: a build goes to a temporary folder beside the target
//! and is renamed into place at the end, files through temporary names, so an interrupted or
//! failed run never leaves a tileset that looks complete, and a user's folder that is not a
//! tileset is never replaced.

use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// Checks that `out` may be written: absent, or replaceable with `force`.
pub(crate) fn check_output(out: &Path, force: bool) -> Result<()> {
    if !out.exists() {
        return Ok(());
    }
    if !force {
        return Err(Error::output(
            out,
            "output folder exists (use --force to replace it)",
        ));
    }
    if !out.is_dir() {
        return Err(Error::output(out, "output path exists and is not a folder"));
    }
    let empty = std::fs::read_dir(out)
        .map_err(|e| Error::output_from(out, "cannot list the folder", e))?
        .next()
        .is_none();
    if !empty && !out.join("tileset.json").exists() {
        return Err(Error::output(
            out,
            "refusing to replace a folder that does not hold a tileset (no tileset.json)",
        ));
    }
    Ok(())
}

/// Writes `bytes` to `path` through a temporary name beside it (`.NAME.tmp-PID`), renamed at
/// the end: a reader never sees a half-written file under the final name.
pub(crate) fn write_renamed(path: &Path, bytes: &[u8]) -> Result<()> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().to_string())
        .unwrap_or_default();
    let tmp = path.with_file_name(format!(".{name}.tmp-{}", std::process::id()));
    std::fs::write(&tmp, bytes)
        .and_then(|()| std::fs::rename(&tmp, path))
        .map_err(|e| {
            let _ = std::fs::remove_file(&tmp);
            Error::output_from(path, "cannot write", e)
        })
}

/// A build's temporary folder beside its target (`.NAME.tmp-PID`): renamed into place by
/// [`StagingDir::commit`], removed if dropped before (a failed build leaves nothing).
pub struct StagingDir {
    out: PathBuf,
    tmp: PathBuf,
    committed: bool,
}

impl StagingDir {
    /// Creates the staging folder for `out` (its parent folders too), replacing a stale one of
    /// this process.
    pub fn beside(out: &Path) -> Result<StagingDir> {
        let name = out
            .file_name()
            .ok_or_else(|| Error::output(out, "output path has no folder name"))?
            .to_string_lossy()
            .to_string();
        let parent = parent_of(out);
        std::fs::create_dir_all(parent)
            .map_err(|e| Error::output_from(parent, "cannot create the folder", e))?;
        let tmp = parent.join(format!(".{name}.tmp-{}", std::process::id()));
        if tmp.exists() {
            std::fs::remove_dir_all(&tmp)
                .map_err(|e| Error::output_from(&tmp, "cannot remove a stale build folder", e))?;
        }
        Ok(StagingDir {
            out: out.to_path_buf(),
            tmp,
            committed: false,
        })
    }

    pub fn path(&self) -> &Path {
        &self.tmp
    }

    /// Writes the last `files` (name, bytes) and puts the folder in place of the target: an
    /// existing target is moved aside first and removed only once the new folder is in place.
    pub fn commit(mut self, files: &[(&str, &[u8])]) -> Result<()> {
        let out = self.out.clone();
        let name = out.file_name().map(|n| n.to_string_lossy().to_string());
        let finish = || -> std::io::Result<()> {
            for (file, bytes) in files {
                std::fs::write(self.tmp.join(file), bytes)?;
            }
            if out.exists() {
                let old = parent_of(&out).join(format!(
                    ".{}.old-{}",
                    name.as_deref().unwrap_or_default(),
                    std::process::id()
                ));
                std::fs::rename(&out, &old)?;
                std::fs::rename(&self.tmp, &out)?;
                std::fs::remove_dir_all(&old)?;
            } else {
                std::fs::rename(&self.tmp, &out)?;
            }
            Ok(())
        };
        finish().map_err(|e| Error::output_from(&out, "cannot put the tileset in place", e))?;
        self.committed = true;
        Ok(())
    }
}

impl Drop for StagingDir {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_dir_all(&self.tmp);
        }
    }
}

/// The folder `out` is in (`.` for a bare name).
fn parent_of(out: &Path) -> &Path {
    out.parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}
