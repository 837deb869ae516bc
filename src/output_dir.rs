//! The output folder, written atomically and never at the cost of a folder the user did not ask
//! to replace (book: guide/safety.md).
//!
//! - A build goes to a temporary folder beside the target (`.NAME.tmp-PID`), files through
//!   temporary names, so an interrupted or failed run never leaves a tileset that looks complete.
//! - One run at a time per output: a lock file beside it (`.NAME.lock`, `flock`), taken before the
//!   target is checked and held until the end. A second run to the same output fails at once.
//! - The final move is `renameat2`: `RENAME_NOREPLACE` when there was no target, so a folder that
//!   appeared meanwhile is never clobbered; `RENAME_EXCHANGE` when `--force` replaces a tileset,
//!   after checking that the target is still the folder that was checked, so the user's tileset
//!   is never left aside under another name.
//! - Temporary folders of runs that died (their PID is gone) are removed by the next run to the
//!   same output; a failed run removes its temporary folder and the parent folders it created.

use crate::error::{Error, Result};
use std::ffi::CString;
use std::fs::File;
use std::os::unix::ffi::OsStrExt;
use std::os::unix::fs::MetadataExt;
use std::os::unix::io::AsRawFd;
use std::path::{Path, PathBuf};

/// Checks that `out` may be written: absent, or with `force` an empty folder or one holding one
/// of `markers` (the files of what bimtiles writes there); `what` names them for the error.
pub(crate) fn check_replaceable(
    out: &Path,
    force: bool,
    markers: &[&str],
    what: &str,
) -> Result<()> {
    let Ok(meta) = std::fs::symlink_metadata(out) else {
        return Ok(());
    };
    if !force {
        return Err(Error::output(
            out,
            "output folder exists (use --force to replace it)",
        ));
    }
    if !meta.is_dir() {
        return Err(Error::output(out, "output path exists and is not a folder"));
    }
    let empty = std::fs::read_dir(out)
        .map_err(|e| Error::output_from(out, "cannot list the folder", e))?
        .next()
        .is_none();
    if !empty && !markers.iter().any(|m| out.join(m).exists()) {
        return Err(Error::output(
            out,
            format!("refusing to replace a folder that does not hold {what}"),
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

/// The identity of a folder (device and inode), to tell whether a path still names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct FolderId {
    dev: u64,
    ino: u64,
}

fn folder_id(path: &Path) -> Option<FolderId> {
    std::fs::symlink_metadata(path).ok().map(|m| FolderId {
        dev: m.dev(),
        ino: m.ino(),
    })
}

/// The lock of one output (`.NAME.lock` beside it), released and removed on drop.
struct OutputLock {
    path: PathBuf,
    _file: File,
}

impl OutputLock {
    /// Takes the lock without waiting; `Err` names the run that holds it.
    fn take(out: &Path, lock_path: PathBuf) -> Result<OutputLock> {
        loop {
            let file = std::fs::OpenOptions::new()
                .create(true)
                .truncate(false)
                .read(true)
                .write(true)
                .open(&lock_path)
                .map_err(|e| Error::output_from(&lock_path, "cannot create the lock file", e))?;
            // SAFETY: flock on a descriptor this function owns.
            if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } != 0 {
                let holder = std::fs::read_to_string(&lock_path).unwrap_or_default();
                return Err(Error::output(
                    out,
                    format!(
                        "another bimtiles run is writing this output (process {}); wait for it, or choose another --out",
                        holder.trim()
                    ),
                ));
            }
            // The holder before us may have removed the file between our open and our lock: the
            // lock must be on the file the path names now.
            let held = file.metadata().map(|m| (m.dev(), m.ino())).ok();
            let named = std::fs::metadata(&lock_path)
                .map(|m| (m.dev(), m.ino()))
                .ok();
            if held.is_some() && held == named {
                let _ = file.set_len(0);
                let _ = std::io::Write::write_all(
                    &mut &file,
                    std::process::id().to_string().as_bytes(),
                );
                return Ok(OutputLock {
                    path: lock_path,
                    _file: file,
                });
            }
        }
    }
}

impl Drop for OutputLock {
    fn drop(&mut self) {
        // Removed while still held: a run that opened it before sees a stale file and retries.
        let _ = std::fs::remove_file(&self.path);
    }
}

/// A build's temporary folder beside its target (`.NAME.tmp-PID`): put in place by
/// [`StagingDir::commit`]; removed if dropped before, with the parent folders it created (a
/// failed build leaves nothing).
pub struct StagingDir {
    out: PathBuf,
    tmp: PathBuf,
    /// The folder at `out` when the build started (checked replaceable), if there was one.
    replaces: Option<FolderId>,
    /// Folders created for the output's parent, outermost first.
    created_parents: Vec<PathBuf>,
    committed: bool,
    lock: Option<OutputLock>,
}

impl StagingDir {
    /// Takes the output's lock, checks under it that `out` may be written (absent, or with
    /// `force` an empty folder or a tileset: [`check_replaceable`]), removes the temporary folders
    /// of dead runs, and creates the staging folder (and the parent folders).
    pub fn beside(out: &Path, force: bool) -> Result<StagingDir> {
        Self::beside_for(out, force, &["tileset.json"], "a tileset (no tileset.json)")
    }

    /// [`StagingDir::beside`] for an output recognised by other marker files (see
    /// [`check_replaceable`]).
    pub(crate) fn beside_for(
        out: &Path,
        force: bool,
        markers: &[&str],
        what: &str,
    ) -> Result<StagingDir> {
        let name = out
            .file_name()
            .ok_or_else(|| Error::output(out, "output path has no folder name"))?
            .to_string_lossy()
            .to_string();
        let parent = parent_of(out).to_path_buf();
        let created_parents = create_parents(&parent)?;
        let mut staging = StagingDir {
            out: out.to_path_buf(),
            tmp: parent.join(format!(".{name}.tmp-{}", std::process::id())),
            replaces: None,
            created_parents,
            committed: false,
            lock: None,
        };
        staging.lock = Some(OutputLock::take(out, parent.join(format!(".{name}.lock")))?);
        check_replaceable(out, force, markers, what)?;
        staging.replaces = folder_id(out);
        remove_dead_runs(&parent, &name);
        if staging.tmp.exists() {
            std::fs::remove_dir_all(&staging.tmp).map_err(|e| {
                Error::output_from(&staging.tmp, "cannot remove a stale build folder", e)
            })?;
        }
        std::fs::create_dir(&staging.tmp)
            .map_err(|e| Error::output_from(&staging.tmp, "cannot create the build folder", e))?;
        Ok(staging)
    }

    pub fn path(&self) -> &Path {
        &self.tmp
    }

    /// The output this folder becomes.
    pub fn target(&self) -> &Path {
        &self.out
    }

    /// Writes the last `files` (name, bytes) and puts the folder in place of the target. A target
    /// that appeared, or was replaced, since the build started is left as it is: the build then
    /// fails and its folder is removed.
    pub fn commit(mut self, files: &[(&str, &[u8])]) -> Result<()> {
        for (file, bytes) in files {
            let path = self.tmp.join(file);
            std::fs::write(&path, bytes)
                .map_err(|e| Error::output_from(self.out.join(file), "cannot write", e))?;
        }
        let now = folder_id(&self.out);
        match (self.replaces, now) {
            (_, None) => rename_no_replace(&self.tmp, &self.out).map_err(|e| {
                if e.kind() == std::io::ErrorKind::AlreadyExists
                    || e.raw_os_error() == Some(libc::ENOTEMPTY)
                {
                    appeared(&self.out)
                } else {
                    Error::output_from(&self.out, "cannot put the tileset in place", e)
                }
            })?,
            (Some(was), Some(is)) if was == is => {
                exchange(&self.tmp, &self.out).map_err(|e| {
                    Error::output_from(&self.out, "cannot put the tileset in place", e)
                })?;
                if folder_id(&self.tmp) != Some(was) {
                    // Replaced between the check and the exchange: give it back.
                    let _ = exchange(&self.tmp, &self.out);
                    return Err(appeared(&self.out));
                }
                // The old tileset now sits at the temporary name; a failure to remove it leaves
                // a dead run's folder, which the next run removes.
                let _ = std::fs::remove_dir_all(&self.tmp);
            }
            _ => return Err(appeared(&self.out)),
        }
        self.committed = true;
        Ok(())
    }
}

fn appeared(out: &Path) -> Error {
    Error::output(
        out,
        "a folder appeared (or was replaced) there during the build; it was left as it is and nothing was written",
    )
}

impl Drop for StagingDir {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_dir_all(&self.tmp);
        }
        self.lock = None;
        if !self.committed {
            // Innermost first; a folder that is not empty (something else was put there) stays.
            for dir in self.created_parents.iter().rev() {
                if std::fs::remove_dir(dir).is_err() {
                    break;
                }
            }
        }
    }
}

/// Creates `dir` and its missing ancestors; returns the folders created, outermost first.
fn create_parents(dir: &Path) -> Result<Vec<PathBuf>> {
    let missing: Vec<PathBuf> = dir
        .ancestors()
        .take_while(|d| !d.as_os_str().is_empty() && std::fs::symlink_metadata(d).is_err())
        .map(Path::to_path_buf)
        .collect();
    std::fs::create_dir_all(dir)
        .map_err(|e| Error::output_from(dir, "cannot create the folder", e))?;
    Ok(missing.into_iter().rev().collect())
}

/// Removes `.NAME.tmp-PID` and `.NAME.old-PID` (older versions) beside the output whose process
/// is gone. Called under the output's lock, so no live run of ours owns them.
fn remove_dead_runs(parent: &Path, name: &str) {
    let Ok(entries) = std::fs::read_dir(parent) else {
        return;
    };
    let prefixes = [format!(".{name}.tmp-"), format!(".{name}.old-")];
    for entry in entries.flatten() {
        let file_name = entry.file_name().to_string_lossy().to_string();
        let pid = prefixes
            .iter()
            .find_map(|p| file_name.strip_prefix(p.as_str()))
            .and_then(|pid| pid.parse::<i32>().ok());
        if pid.is_some_and(|pid| pid > 0 && !process_alive(pid)) {
            let _ = std::fs::remove_dir_all(entry.path());
        }
    }
}

fn process_alive(pid: i32) -> bool {
    // SAFETY: signal 0 sends nothing; it only asks whether the process exists.
    let r = unsafe { libc::kill(pid, 0) };
    r == 0 || std::io::Error::last_os_error().raw_os_error() != Some(libc::ESRCH)
}

fn c_path(p: &Path) -> std::io::Result<CString> {
    CString::new(p.as_os_str().as_bytes())
        .map_err(|_| std::io::Error::new(std::io::ErrorKind::InvalidInput, "NUL in path"))
}

fn renameat2(from: &Path, to: &Path, flags: libc::c_uint) -> std::io::Result<()> {
    let (from, to) = (c_path(from)?, c_path(to)?);
    // SAFETY: two NUL-terminated paths, relative to the working folder.
    let r = unsafe {
        libc::renameat2(
            libc::AT_FDCWD,
            from.as_ptr(),
            libc::AT_FDCWD,
            to.as_ptr(),
            flags,
        )
    };
    match r {
        0 => Ok(()),
        _ => Err(std::io::Error::last_os_error()),
    }
}

/// Renames `from` to `to` unless `to` exists (atomically where the file system has
/// `RENAME_NOREPLACE`; else checked just before the rename).
fn rename_no_replace(from: &Path, to: &Path) -> std::io::Result<()> {
    match renameat2(from, to, libc::RENAME_NOREPLACE) {
        Err(e) if e.raw_os_error() == Some(libc::EINVAL) => {
            if std::fs::symlink_metadata(to).is_ok() {
                return Err(std::io::ErrorKind::AlreadyExists.into());
            }
            std::fs::rename(from, to)
        }
        r => r,
    }
}

/// Swaps `a` and `b` (atomically where the file system has `RENAME_EXCHANGE`; else through a
/// third name).
fn exchange(a: &Path, b: &Path) -> std::io::Result<()> {
    match renameat2(a, b, libc::RENAME_EXCHANGE) {
        Err(e) if e.raw_os_error() == Some(libc::EINVAL) => {
            let mut aside = a.as_os_str().to_owned();
            aside.push(".swap");
            let aside = PathBuf::from(aside);
            std::fs::rename(b, &aside)?;
            std::fs::rename(a, b)?;
            std::fs::rename(&aside, a)
        }
        r => r,
    }
}

/// The folder `out` is in (`.` for a bare name).
fn parent_of(out: &Path) -> &Path {
    out.parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("bimtiles-outdir-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
            .collect();
        v.sort();
        v
    }

    fn build(out: &Path, force: bool, content: &str) -> Result<()> {
        let s = StagingDir::beside(out, force)?;
        std::fs::write(s.path().join("tileset.json"), content).unwrap();
        s.commit(&[("report.json", b"{}")])
    }

    #[test]
    fn a_folder_that_appears_during_the_build_is_left_alone() {
        let d = scratch("appear");
        let out = d.join("out");
        let s = StagingDir::beside(&out, false).unwrap();
        std::fs::create_dir(&out).unwrap();
        std::fs::write(out.join("mine.txt"), "user data").unwrap();
        let e = s.commit(&[]).unwrap_err().to_string();
        assert!(e.contains("appeared"), "{e}");
        assert_eq!(names(&out), vec!["mine.txt"]);
        assert_eq!(names(&d), vec!["out"], "no temporary folder or lock left");
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn force_swaps_a_tileset_in_and_a_replaced_target_is_kept() {
        let d = scratch("force");
        let out = d.join("out");
        build(&out, false, "one").unwrap();
        assert!(build(&out, false, "two").is_err(), "needs --force");
        build(&out, true, "two").unwrap();
        assert_eq!(
            std::fs::read_to_string(out.join("tileset.json")).unwrap(),
            "two"
        );
        assert_eq!(names(&d), vec!["out"]);
        // The tileset checked at the start is replaced by another folder during the build.
        let s = StagingDir::beside(&out, true).unwrap();
        std::fs::rename(&out, d.join("moved")).unwrap();
        std::fs::create_dir(&out).unwrap();
        std::fs::write(out.join("mine.txt"), "user data").unwrap();
        assert!(s.commit(&[]).is_err());
        assert_eq!(names(&out), vec!["mine.txt"]);
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn one_run_at_a_time_per_output() {
        let d = scratch("lock");
        let out = d.join("out");
        let first = StagingDir::beside(&out, false).unwrap();
        let e = StagingDir::beside(&out, false).err().unwrap().to_string();
        assert!(e.contains("another bimtiles run"), "{e}");
        drop(first);
        assert!(StagingDir::beside(&out, false).is_ok());
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn folders_of_dead_runs_are_removed_and_live_ones_kept() {
        let d = scratch("dead");
        let out = d.join("out");
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let dead = child.id();
        child.wait().unwrap();
        let dead_tmp = d.join(format!(".out.tmp-{dead}"));
        let dead_old = d.join(format!(".out.old-{dead}"));
        let live = d.join(".out.tmp-1"); // init never dies
        let other = d.join(format!(".other.tmp-{dead}"));
        for f in [&dead_tmp, &dead_old, &live, &other] {
            std::fs::create_dir_all(f.join("tiles")).unwrap();
        }
        build(&out, false, "x").unwrap();
        assert!(!dead_tmp.exists() && !dead_old.exists());
        assert!(live.exists() && other.exists());
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn a_failed_build_removes_the_parents_it_created() {
        let d = scratch("parents");
        let out = d.join("a/b/out");
        drop(StagingDir::beside(&out, false).unwrap());
        assert_eq!(names(&d), Vec::<String>::new());
        // Parents that existed stay.
        std::fs::create_dir(d.join("a")).unwrap();
        drop(StagingDir::beside(&out, false).unwrap());
        assert_eq!(names(&d), vec!["a"]);
        assert_eq!(names(&d.join("a")), Vec::<String>::new());
        let _ = std::fs::remove_dir_all(&d);
    }
}
