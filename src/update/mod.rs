//! Updating a published tileset (`convert --update`, book: guide/updating.md): the versioned state
//! a build leaves in its output, the check that tells an update what it has to do, and the
//! publication of a new build over the live tileset in which every file whose bytes did not change
//! stays the very same file (same name, same bytes, same inode and modification time).
//!
//! The state is `.bimtiles/update-state.json` in the output folder: a dot-folder, which `serve`
//! refuses and no tileset file references, so the tileset loads without it. It holds the format
//! version, the tool version, a fingerprint of the options that shape the output, the SHA-256 of
//! every input file the build read (the inputs given, every model a manifest placed, and the files
//! beside a model that it may reference: buffers, images, materials), and the name and size of
//! every file of the tileset. Every `--update` writes it into its build folder before that folder
//! is put in place, so it always describes the tileset it sits in; a plain `convert` writes none
//! (its output is the tileset and its report), so the first update after one is a full build.
//!
//! An update whose inputs, options and tool version match the state, over a tileset whose files
//! are all there, reads no model: it only hashes the inputs and rewrites report.json. Otherwise it
//! builds the whole tileset again (a full build, so the result is the one `convert` gives), names
//! the reason in one line, and publishes it with [`reuse_unchanged_files`]: the live tileset stays
//! complete and servable until one atomic exchange of the two folders.

use crate::error::{Error, Result};
use crate::options::Settings;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// The state's folder in the output (hidden: never served, never referenced by the tileset).
pub const STATE_DIR: &str = ".bimtiles";
/// The state file, relative to the output folder.
pub const STATE_FILE: &str = ".bimtiles/update-state.json";
/// The state's format; a state of another format is not used (the update is a full build).
pub const STATE_FORMAT: u32 = 1;
/// The report, rewritten by every run: not a tileset file.
const REPORT_FILE: &str = "report.json";

/// Extensions of the files a model may reference beside it (glTF buffers and images, OBJ
/// materials and textures, CityGML and CityJSON textures): hashed with the model.
const RESOURCE_EXTENSIONS: &[&str] = &[
    "bin", "png", "jpg", "jpeg", "webp", "ktx2", "basis", "gif", "bmp", "tga", "tif", "tiff",
    "dds", "mtl",
];
/// How deep below a model's folder referenced files are looked for.
const RESOURCE_DEPTH: usize = 4;
/// More referenced files than this below the models' folders are not tracked: every update of
/// such inputs is a full build.
const MAX_TRACKED_FILES: usize = 20_000;

/// This binary's version, as `--version` prints it: a state written by another is not used.
pub fn tool_version() -> String {
    format!(
        "bimtiles {} ({})",
        env!("CARGO_PKG_VERSION"),
        env!("BIMTILES_COMMIT")
    )
}

/// One input file and the SHA-256 of its bytes.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct InputHash {
    pub path: PathBuf,
    pub bytes: u64,
    pub sha256: String,
}

/// One file of the tileset (path relative to the output folder, `/`-separated).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct OutputFile {
    pub path: String,
    pub bytes: u64,
}

/// What a build leaves in `.bimtiles/update-state.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UpdateState {
    pub format: u32,
    pub tool_version: String,
    /// SHA-256 of the options that shape the output ([`options_fingerprint`]).
    pub options_sha256: String,
    /// The inputs as given: model files, or one manifest (empty: the bundled sample).
    pub given: Vec<PathBuf>,
    /// Every file read, with its hash (`None`: too many to track; every update rebuilds).
    pub inputs: Option<Vec<InputHash>>,
    pub files: Vec<OutputFile>,
}

/// What `--update` did (report.json's `update`).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct UpdateReport {
    /// `unchanged` (nothing to rebuild: no model read) or `rebuilt` (a full build, published
    /// over the old tileset).
    pub mode: &'static str,
    /// Why the tileset was built again (absent when it was not).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub full_build_reason: Option<String>,
    /// Input files whose bytes changed, were added or were removed since the last build.
    pub changed_inputs: Vec<String>,
    /// Input files hashed, and their bytes.
    pub inputs_hashed: usize,
    pub input_bytes_hashed: u64,
    /// Tileset files kept as they were (same name, bytes and inode).
    pub files_reused: usize,
    pub bytes_reused: u64,
    /// Tileset files new or with new bytes.
    pub files_written: usize,
    pub bytes_written: u64,
    /// Files of the old tileset no longer in it, removed; or kept with `--keep-stale`.
    pub files_removed: usize,
    pub bytes_removed: u64,
    pub files_kept_stale: usize,
    /// Size of the update state file.
    pub state_bytes: u64,
    /// Tiles built (every leaf, and the internal tiles not taken from the tile cache), and their
    /// files' bytes.
    pub tiles_built: usize,
    pub tile_bytes_built: u64,
    /// Internal (HLOD) tiles of the tileset, and those built.
    pub internal_tiles: usize,
    pub internal_tiles_built: usize,
    /// Internal tiles taken from the tile cache (not simplified, measured or encoded), and their
    /// files' bytes.
    pub tiles_reused: usize,
    pub tile_bytes_reused: u64,
    /// Internal tiles whose file was written again from the geometry in the tile cache (only
    /// their elements' metadata changed): not simplified or measured.
    pub tiles_rewritten: usize,
    /// Internal tiles found in the tile cache whose hand-over (the geometry a parent built again
    /// simplifies) was made again from its recipe: simplified, not measured.
    pub tiles_remade: usize,
    /// Leaves whose file was taken from the live tileset (their geometry and their elements'
    /// metadata as they were: not encoded), and their files' bytes.
    pub leaves_reused: usize,
    pub leaf_bytes_reused: u64,
    /// Size of the tile cache file written.
    pub tile_cache_bytes: u64,
    /// Why the tile cache could not be used (absent when it was, or there was no tileset yet).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tile_cache_note: Option<String>,
    pub seconds: f64,
}

impl UpdateReport {
    /// The summary's line.
    pub fn summary(&self) -> String {
        let mut s = format!(
            "update: {}; {} files reused ({} bytes), {} written ({} bytes), {} removed ({} bytes)",
            self.mode,
            self.files_reused,
            self.bytes_reused,
            self.files_written,
            self.bytes_written,
            self.files_removed,
            self.bytes_removed
        );
        if self.files_kept_stale > 0 {
            s += &format!(", {} stale kept", self.files_kept_stale);
        }
        if self.mode == "rebuilt" {
            s += &format!(
                "\nupdate: {} tiles written ({} bytes), of them {} of {} HLOD tiles built and {} written again from the tile cache; {} HLOD tiles ({} bytes) and {} leaves ({} bytes) reused from the tile cache; {} simplified again for their parents; tile cache {} bytes",
                self.tiles_built,
                self.tile_bytes_built,
                self.internal_tiles_built,
                self.internal_tiles,
                self.tiles_rewritten,
                self.tiles_reused,
                self.tile_bytes_reused,
                self.leaves_reused,
                self.leaf_bytes_reused,
                self.tiles_remade,
                self.tile_cache_bytes
            );
        }
        if let Some(r) = self.build_note() {
            s += &format!("\nupdate: {r}");
        }
        s
    }

    /// Why the tileset was built again, and whether that was a full build (no tile taken from
    /// the tile cache, and why); one line.
    pub fn build_note(&self) -> Option<String> {
        let reason = self.full_build_reason.as_ref()?;
        let from_cache = self.tiles_reused + self.tiles_rewritten;
        Some(match (from_cache, &self.tile_cache_note) {
            (0, Some(note)) => format!("full build: {reason}; {note}"),
            (0, None) => format!("full build: {reason}"),
            (_, _) => format!(
                "{reason}; {} of {} HLOD tiles reused from the tile cache, {} written again from it",
                self.tiles_reused, self.internal_tiles, self.tiles_rewritten
            ),
        })
    }
}

/// The options that shape the output, as one hash: everything but where the output goes, whether
/// it may replace a folder, progress and the update's own switches.
pub fn options_fingerprint(opts: &Settings) -> String {
    let mut shaping = opts.clone();
    shaping.asked.out_dir = PathBuf::new();
    shaping.asked.force = false;
    shaping.asked.progress = false;
    shaping.asked.update = false;
    shaping.asked.keep_stale = false;
    hex(&Sha256::digest(format!("{shaping:?}").as_bytes()))
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// SHA-256 of a file's bytes, streamed through the hasher.
fn hash_file(path: &Path) -> std::io::Result<InputHash> {
    let mut h = Sha256::new();
    let bytes = std::io::copy(&mut std::fs::File::open(path)?, &mut h)?;
    Ok(InputHash {
        path: path.to_path_buf(),
        bytes,
        sha256: hex(&h.finalize()),
    })
}

/// The files a build read: the inputs given, the models read (`sources`), and the files beside
/// each model that it may reference. `None` when there are too many to track.
pub fn input_files(given: &[PathBuf], sources: &[PathBuf]) -> Option<Vec<PathBuf>> {
    let mut files: BTreeSet<PathBuf> = given.iter().chain(sources).cloned().collect();
    let folders: BTreeSet<PathBuf> = sources
        .iter()
        .filter(|s| !has_extension(s, &["ifc"]))
        .map(|s| match s.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        })
        .collect();
    for folder in &folders {
        collect_resources(folder, RESOURCE_DEPTH, &mut files);
        if files.len() > MAX_TRACKED_FILES {
            return None;
        }
    }
    Some(files.into_iter().collect())
}

fn has_extension(path: &Path, extensions: &[&str]) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| extensions.iter().any(|x| e.eq_ignore_ascii_case(x)))
}

/// The files below `dir` a model may reference. Dot-entries (a build's staging folder, the update
/// cache) and folders holding a `tileset.json` (a tileset, such as the output itself when it sits
/// beside the models) are outputs, not inputs: hashing them would see every build change them.
fn collect_resources(dir: &Path, depth: usize, files: &mut BTreeSet<PathBuf>) {
    if dir.join("tileset.json").is_file() {
        return;
    }
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        if entry.file_name().to_string_lossy().starts_with('.') {
            continue;
        }
        let path = entry.path();
        let Ok(kind) = entry.file_type() else {
            continue;
        };
        if kind.is_dir() && depth > 0 {
            collect_resources(&path, depth - 1, files);
        } else if kind.is_file() && has_extension(&path, RESOURCE_EXTENSIONS) {
            files.insert(path);
        }
        if files.len() > MAX_TRACKED_FILES {
            return;
        }
    }
}

/// Hashes `files`; a file that cannot be read names itself in the error.
pub fn hash_inputs(files: &[PathBuf]) -> Result<Vec<InputHash>> {
    use rayon::prelude::*;
    files
        .par_iter()
        .map(|f| hash_file(f).map_err(|e| Error::input_from(f, "cannot read", e)))
        .collect()
}

/// The state of a finished build in `dir` (its files listed from the folder, report.json and the
/// state's folder left out).
pub fn state_of(
    dir: &Path,
    opts: &Settings,
    given: &[PathBuf],
    inputs: Option<Vec<InputHash>>,
) -> Result<UpdateState> {
    Ok(UpdateState {
        format: STATE_FORMAT,
        tool_version: tool_version(),
        options_sha256: options_fingerprint(opts),
        given: given.to_vec(),
        inputs,
        files: tileset_files(dir)?,
    })
}

impl UpdateState {
    /// Writes the state into the build folder `dir`.
    pub fn write_into(&self, dir: &Path) -> Result<u64> {
        let path = dir.join(STATE_FILE);
        let folder = dir.join(STATE_DIR);
        std::fs::create_dir_all(&folder)
            .map_err(|e| Error::output_from(&folder, "cannot create the folder", e))?;
        let bytes = serde_json::to_vec_pretty(self)
            .map_err(|e| Error::output_from(&path, "cannot serialize", e))?;
        crate::output_dir::write_renamed(&path, &bytes)?;
        Ok(bytes.len() as u64)
    }
}

/// Every file of the tileset in `dir`, sorted by path: all files but report.json and the state.
pub fn tileset_files(dir: &Path) -> Result<Vec<OutputFile>> {
    let mut out = Vec::new();
    list_files(dir, "", &mut out)?;
    out.sort_by(|a, b| a.path.cmp(&b.path));
    Ok(out)
}

fn list_files(dir: &Path, prefix: &str, out: &mut Vec<OutputFile>) -> Result<()> {
    let entries =
        std::fs::read_dir(dir).map_err(|e| Error::output_from(dir, "cannot list the folder", e))?;
    for entry in entries {
        let entry = entry.map_err(|e| Error::output_from(dir, "cannot list the folder", e))?;
        let name = entry.file_name().to_string_lossy().to_string();
        if prefix.is_empty() && (name == REPORT_FILE || name == STATE_DIR) {
            continue;
        }
        let rel = format!("{prefix}{name}");
        let meta = std::fs::symlink_metadata(entry.path())
            .map_err(|e| Error::output_from(entry.path(), "cannot read", e))?;
        if meta.is_dir() {
            list_files(&entry.path(), &format!("{rel}/"), out)?;
        } else if meta.is_file() {
            out.push(OutputFile {
                path: rel,
                bytes: meta.len(),
            });
        }
    }
    Ok(())
}

/// What an update has to do.
#[derive(Debug)]
pub enum Verdict {
    /// Inputs, options and tool are those of the tileset (described by `state`): nothing to build.
    Unchanged {
        state: UpdateState,
        hashed: Vec<InputHash>,
    },
    /// A full build, for this reason (one line); `changed` names the inputs that changed.
    Rebuild {
        reason: String,
        changed: Vec<String>,
        hashed: Vec<InputHash>,
    },
}

fn rebuild(reason: impl Into<String>) -> Verdict {
    Verdict::Rebuild {
        reason: reason.into(),
        changed: Vec::new(),
        hashed: Vec::new(),
    }
}

/// Compares the tileset in `out` and its state with the inputs `given` and the options.
pub fn check(out: &Path, given: &[PathBuf], opts: &Settings) -> Verdict {
    let path = out.join(STATE_FILE);
    let text = match std::fs::read(&path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return rebuild(format!("no update cache ({STATE_FILE}) in the output"))
        }
        Err(e) => return rebuild(format!("the update cache cannot be read ({e})")),
    };
    let format = serde_json::from_slice::<serde_json::Value>(&text)
        .ok()
        .and_then(|v| v["format"].as_u64());
    if format.is_some_and(|f| f != u64::from(STATE_FORMAT)) {
        return rebuild(format!(
            "the update cache has format {}, this version uses {STATE_FORMAT}",
            format.unwrap_or_default()
        ));
    }
    let state: UpdateState = match serde_json::from_slice(&text) {
        Ok(s) => s,
        Err(e) => return rebuild(format!("the update cache is corrupt ({e})")),
    };
    if state.tool_version != tool_version() {
        return rebuild(format!(
            "the tool version changed ({} before, {} now)",
            state.tool_version,
            tool_version()
        ));
    }
    if state.options_sha256 != options_fingerprint(opts) {
        return rebuild("the options changed");
    }
    if state.given != given {
        return rebuild("the inputs given changed");
    }
    if !out.join(REPORT_FILE).is_file() {
        return rebuild("report.json is missing from the output");
    }
    if let Some(f) = state.files.iter().find(|f| {
        std::fs::symlink_metadata(out.join(&f.path))
            .map_or(true, |m| !m.is_file() || m.len() != f.bytes)
    }) {
        return rebuild(format!(
            "the tileset's file {} changed since the last build",
            f.path
        ));
    }
    let Some(before) = state.inputs else {
        return rebuild(format!(
            "the models' folders hold more than {MAX_TRACKED_FILES} files that they may reference: not tracked"
        ));
    };
    let files: Vec<PathBuf> = before.iter().map(|i| i.path.clone()).collect();
    // A file that is gone is a change (the build will say what it misses).
    let hashed: Vec<Option<InputHash>> = {
        use rayon::prelude::*;
        files.par_iter().map(|f| hash_file(f).ok()).collect()
    };
    let changed: Vec<String> = before
        .iter()
        .zip(&hashed)
        .filter(|(b, now)| now.as_ref() != Some(b))
        .map(|(b, _)| b.path.display().to_string())
        .collect();
    let hashed: Vec<InputHash> = hashed.into_iter().flatten().collect();
    match changed.len() {
        0 => Verdict::Unchanged {
            state: UpdateState {
                inputs: Some(before),
                ..state
            },
            hashed,
        },
        n => Verdict::Rebuild {
            reason: format!(
                "{n} input file{} changed ({})",
                if n == 1 { "" } else { "s" },
                shorten(&changed)
            ),
            changed,
            hashed,
        },
    }
}

/// The first few names of a list, for a one-line reason.
fn shorten(names: &[String]) -> String {
    const SHOWN: usize = 3;
    let mut s = names
        .iter()
        .take(SHOWN)
        .cloned()
        .collect::<Vec<_>>()
        .join(", ");
    if names.len() > SHOWN {
        s += &format!(" and {} more", names.len() - SHOWN);
    }
    s
}

/// Whether `a` and `b` are files of `len` bytes with the same bytes.
fn same_bytes(a: &Path, b: &Path, len: u64) -> bool {
    match (std::fs::symlink_metadata(a), std::fs::symlink_metadata(b)) {
        (Ok(ma), Ok(mb)) if ma.is_file() && mb.is_file() && ma.len() == len && mb.len() == len => {
            matches!((std::fs::read(a), std::fs::read(b)), (Ok(x), Ok(y)) if x == y)
        }
        _ => false,
    }
}

/// Replaces `at` by a hard link to `from` (through a temporary name, so `at` is never missing).
fn link_over(from: &Path, at: &Path) -> std::io::Result<()> {
    use std::os::unix::fs::MetadataExt;
    // Already that file (a tile taken from the tile cache): renaming a link over another link
    // of the same file does nothing, and would leave the temporary name.
    let (a, b) = (std::fs::metadata(from)?, std::fs::metadata(at)?);
    if (a.dev(), a.ino()) == (b.dev(), b.ino()) {
        return Ok(());
    }
    let name = at
        .file_name()
        .map(|n| n.to_string_lossy().to_string())
        .unwrap_or_default();
    let tmp = at.with_file_name(format!(".{name}.link-{}", std::process::id()));
    let _ = std::fs::remove_file(&tmp);
    std::fs::hard_link(from, &tmp)?;
    std::fs::rename(&tmp, at).inspect_err(|_| {
        let _ = std::fs::remove_file(&tmp);
    })
}

/// Prepares the build folder `staging` to replace the live tileset `live`: every file of the new
/// tileset whose bytes equal the live file of the same name becomes that very file (a hard link:
/// same inode and modification time, so HTTP validators and copies stay valid); with
/// `keep_stale`, the live files the new tileset no longer has are linked in too, for clients that
/// still hold the old tileset.json. Counts go into `report`.
pub fn reuse_unchanged_files(
    staging: &Path,
    live: &Path,
    keep_stale: bool,
    report: &mut UpdateReport,
) -> Result<()> {
    let new_files = tileset_files(staging)?;
    let old_files = match live.is_dir() {
        true => tileset_files(live)?,
        false => Vec::new(),
    };
    let new_names: BTreeSet<&str> = new_files.iter().map(|f| f.path.as_str()).collect();
    for f in &new_files {
        let (at, from) = (staging.join(&f.path), live.join(&f.path));
        // A file that cannot be linked stays the new copy: same bytes either way.
        if same_bytes(&at, &from, f.bytes) && link_over(&from, &at).is_ok() {
            report.files_reused += 1;
            report.bytes_reused += f.bytes;
        } else {
            report.files_written += 1;
            report.bytes_written += f.bytes;
        }
    }
    for f in old_files
        .iter()
        .filter(|f| !new_names.contains(f.path.as_str()))
    {
        let at = staging.join(&f.path);
        let kept = keep_stale
            && at
                .parent()
                .is_some_and(|p| std::fs::create_dir_all(p).is_ok())
            && std::fs::hard_link(live.join(&f.path), &at).is_ok();
        if kept {
            report.files_kept_stale += 1;
        } else {
            report.files_removed += 1;
            report.bytes_removed += f.bytes;
        }
    }
    Ok(())
}

/// The files of a tileset folder that its tileset no longer has (kept by an earlier
/// `--keep-stale`).
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct StaleFiles {
    pub removed: usize,
    pub removed_bytes: u64,
    pub kept: usize,
}

/// Removes the files of `out` that are not among the tileset's `files` (report.json and the
/// state aside), unless `keep_stale`: no tileset.json names them.
pub fn settle_stale_files(
    out: &Path,
    files: &[OutputFile],
    keep_stale: bool,
) -> Result<StaleFiles> {
    let current: BTreeSet<&str> = files.iter().map(|f| f.path.as_str()).collect();
    let mut settled = StaleFiles::default();
    for f in tileset_files(out)?
        .into_iter()
        .filter(|f| !current.contains(f.path.as_str()))
    {
        if keep_stale {
            settled.kept += 1;
            continue;
        }
        let path = out.join(&f.path);
        std::fs::remove_file(&path)
            .map_err(|e| Error::output_from(&path, "cannot remove a stale file", e))?;
        settled.removed += 1;
        settled.removed_bytes += f.bytes;
    }
    Ok(settled)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::MetadataExt;

    fn scratch(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("bimtiles-update-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    fn put(dir: &Path, rel: &str, bytes: &[u8]) {
        let p = dir.join(rel);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, bytes).unwrap();
    }

    fn settings() -> Settings {
        crate::options::ConvertOptions::new("out").resolve()
    }

    #[test]
    fn unchanged_files_become_the_live_files_and_stale_ones_are_counted() {
        let d = scratch("reuse");
        let (live, staging) = (d.join("live"), d.join("staging"));
        for (dir, tile) in [(&live, b"old".as_slice()), (&staging, b"new".as_slice())] {
            put(dir, "tileset.json", b"{}");
            put(dir, "tiles/r.glb", b"same");
            put(dir, "tiles/r0.glb", tile);
            put(dir, "report.json", tile);
        }
        put(&live, "tiles/r1.glb", b"gone");
        put(&staging, "tiles/r2.glb", b"added");
        let mut report = UpdateReport::default();
        reuse_unchanged_files(&staging, &live, false, &mut report).unwrap();
        let ino = |p: PathBuf| std::fs::metadata(p).unwrap().ino();
        assert_eq!(
            ino(staging.join("tiles/r.glb")),
            ino(live.join("tiles/r.glb"))
        );
        assert_ne!(
            ino(staging.join("tiles/r0.glb")),
            ino(live.join("tiles/r0.glb"))
        );
        assert_eq!(std::fs::read(staging.join("tiles/r0.glb")).unwrap(), b"new");
        assert_eq!((report.files_reused, report.bytes_reused), (2, 6));
        assert_eq!((report.files_written, report.bytes_written), (2, 8));
        assert_eq!((report.files_removed, report.bytes_removed), (1, 4));
        assert!(!staging.join("tiles/r1.glb").exists());
        let mut kept = UpdateReport::default();
        reuse_unchanged_files(&staging, &live, true, &mut kept).unwrap();
        assert_eq!((kept.files_kept_stale, kept.files_removed), (1, 0));
        assert_eq!(
            std::fs::read(staging.join("tiles/r1.glb")).unwrap(),
            b"gone"
        );
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn the_check_names_each_reason_for_a_full_build() {
        let d = scratch("check");
        let out = d.join("out");
        let model = d.join("m.glb");
        std::fs::write(&model, b"model").unwrap();
        put(&out, "tileset.json", b"{}");
        put(&out, "report.json", b"{}");
        let opts = settings();
        let given = vec![model.clone()];
        let reason = |v: Verdict| match v {
            Verdict::Rebuild { reason, .. } => reason,
            Verdict::Unchanged { .. } => "unchanged".into(),
        };
        assert!(reason(check(&out, &given, &opts)).contains("no update cache"));
        let inputs = hash_inputs(&input_files(&given, &given).unwrap()).unwrap();
        let state = state_of(&out, &opts, &given, Some(inputs)).unwrap();
        assert_eq!(state.files.len(), 1, "report.json is not a tileset file");
        state.write_into(&out).unwrap();
        assert_eq!(reason(check(&out, &given, &opts)), "unchanged");
        let mut other = opts.clone();
        other.asked.out_dir = "elsewhere".into();
        other.asked.progress = true;
        assert_eq!(reason(check(&out, &given, &other)), "unchanged");
        other.asked.octree.max_tile_triangles += 1;
        assert_eq!(reason(check(&out, &given, &other)), "the options changed");
        std::fs::write(&model, b"model, renamed room").unwrap();
        assert!(reason(check(&out, &given, &opts)).starts_with("1 input file changed"));
        std::fs::write(&model, b"model").unwrap();
        put(&out, "tileset.json", b"{ }");
        assert!(reason(check(&out, &given, &opts)).contains("tileset.json changed"));
        put(&out, "tileset.json", b"{}");
        let mut stale = state.clone();
        stale.tool_version = "bimtiles 0.0.1 (old)".into();
        stale.write_into(&out).unwrap();
        assert!(reason(check(&out, &given, &opts)).contains("tool version changed"));
        stale.format = STATE_FORMAT + 1;
        stale.write_into(&out).unwrap();
        assert!(reason(check(&out, &given, &opts)).contains("has format"));
        put(&out, STATE_FILE, b"{\"format\": 1, \"tool");
        assert!(reason(check(&out, &given, &opts)).contains("corrupt"));
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn files_beside_a_model_that_it_may_reference_are_tracked() {
        let d = scratch("resources");
        put(&d, "a.gltf", b"{}");
        put(&d, "a.bin", b"0");
        put(&d, "tex/wall.png", b"1");
        put(&d, "notes.txt", b"2");
        put(&d, "b.ifc", b"3");
        let files = input_files(&[], &[d.join("a.gltf")]).unwrap();
        let names: Vec<_> = files.iter().map(|f| f.strip_prefix(&d).unwrap()).collect();
        assert_eq!(
            names,
            [
                Path::new("a.bin"),
                Path::new("a.gltf"),
                Path::new("tex/wall.png")
            ]
        );
        // An IFC file references nothing.
        assert_eq!(input_files(&[], &[d.join("b.ifc")]).unwrap().len(), 1);
        let _ = std::fs::remove_dir_all(&d);
    }
}
