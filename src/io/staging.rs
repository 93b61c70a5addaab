//! All-or-nothing outputs (SPEC.md §14.2). A command registers every output folder and file with one
//! [`Staging`] before its heavy work, writes into the staged paths it is given, and calls
//! [`Staging::commit`] at the very end. Until then nothing the user can see has changed; dropping the
//! staging without committing (an error, a panic) removes everything staged.
//!
//! - **A folder** (`reconstruct --out`, `eval --out`, `synth --out`, `train --out`, dumps) is built
//!   as a complete sibling `.NAME.densefeat-stage-PID`: new files are written there, entries of the
//!   old folder that the command does not replace are hard-linked in (copied where links fail), then
//!   the two folders are swapped in one `renameat2(RENAME_EXCHANGE)` and the old one removed. A reader
//!   (or a `kill -9` at any instant) sees the complete old folder or the complete new one. Where the
//!   swap is unsupported (not Linux, or a file system without it) two renames are used, with the old
//!   folder parked as `.NAME.densefeat-old-PID` in between; the next run puts it back if it was
//!   left there.
//! - **A named file** (`costcurve --out`, `features --out/--viz`, `init-weights --out`) is written
//!   as `.NAME.densefeat-tmp-PID` beside it and renamed over it at the commit, file by file.
//!
//! Every `.*.densefeat-{tmp,stage,old}-PID` (and the `.*.tmp-PID` of earlier versions) whose process
//! is gone is disposable: each staging removes those in the folders it touches.

use std::ffi::OsStr;
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// Marker in the names of our temporary files and folders.
pub const TEMP_MARKER: &str = ".densefeat-";

/// One staged output folder.
#[derive(Debug)]
struct DirGroup {
    /// The folder the user named (absolute, its parent's symlinks resolved).
    target: PathBuf,
    /// The sibling it is built in.
    stage: PathBuf,
}

/// One staged output file.
#[derive(Debug)]
struct FileEntry {
    target: PathBuf,
    temp: PathBuf,
}

/// Outputs of one command run, staged until [`Staging::commit`]. See the module docs.
#[derive(Debug, Default)]
pub struct Staging {
    dirs: Vec<DirGroup>,
    files: Vec<FileEntry>,
    /// Folders this staging created (missing parents), removed again if it is dropped uncommitted.
    created: Vec<PathBuf>,
    committed: bool,
}

impl Staging {
    /// An empty staging.
    pub fn new() -> Self {
        Self::default()
    }

    /// Stage the output folder `out` (created at the commit if missing) and return the folder to
    /// write its files into. Stale temporaries of killed runs beside and inside `out` are removed.
    ///
    /// # Errors
    /// [`Error::Io`] naming the folder if it (or its parent) cannot be created or written, if `out`
    /// exists and is not a folder, or if `out` or a folder in it is not writable (its old contents
    /// could not be replaced; checked on the permission bits too, so the refusal holds for root).
    pub fn dir(&mut self, out: &Path) -> Result<PathBuf> {
        let target = self.resolve(out)?;
        if target.exists() && !target.is_dir() {
            return Err(Error::io(out, std::io::Error::other("exists and is not a folder")));
        }
        // The folder is swapped out as a whole at the commit (and at every checkpoint of `train`):
        // a working directory inside it would be pulled from under this process, and every
        // relative path it still has to read would break.
        let cwd = std::env::current_dir().and_then(|d| d.canonicalize());
        if target.is_dir() && cwd.is_ok_and(|d| d.starts_with(&target)) {
            return Err(Error::io(
                out,
                std::io::Error::other(
                    "is the working directory or contains it: the command replaces the whole folder; \
                     run it from outside (e.g. --out ../NAME from inside NAME)",
                ),
            ));
        }
        if target.is_dir() {
            check_writable_tree(&target, out)?;
        }
        let parent = target.parent().map(Path::to_path_buf).unwrap_or_default();
        let name = file_name(&target, out)?;
        recover_parked(&parent, &name);
        clean_stale(&parent);
        if target.is_dir() {
            clean_stale(&target);
        }
        let stage = parent.join(format!(".{name}{TEMP_MARKER}stage-{}", std::process::id()));
        if stage.exists() {
            remove_tree(&stage).map_err(|e| Error::io(&stage, e))?;
        }
        std::fs::create_dir(&stage).map_err(|e| Error::io(out, e))?;
        self.dirs.push(DirGroup { target, stage: stage.clone() });
        Ok(stage)
    }

    /// Stage the output file `path` and return the temporary path to write it to (its folder is
    /// created if missing). Stale temporaries beside it are removed.
    ///
    /// # Errors
    /// [`Error::Io`] naming the file if its folder cannot be created or written, or if `path` is an
    /// existing folder.
    pub fn file(&mut self, path: &Path) -> Result<PathBuf> {
        let target = self.resolve(path)?;
        if target.is_dir() {
            return Err(Error::io(path, std::io::Error::other("is a folder, expected a file name")));
        }
        let parent = target.parent().map(Path::to_path_buf).unwrap_or_default();
        let name = file_name(&target, path)?;
        clean_stale(&parent);
        let temp = parent.join(format!(".{name}{TEMP_MARKER}tmp-{}", std::process::id()));
        if self.files.iter().any(|f| f.target == target) {
            return Err(Error::io(path, std::io::Error::other("named twice as an output")));
        }
        // Prove the folder is writable now, before any heavy work.
        std::fs::write(&temp, b"").map_err(|e| Error::io(path, e))?;
        self.files.push(FileEntry { target, temp: temp.clone() });
        Ok(temp)
    }

    /// Absolute path of `p` with its parent created (recorded) and resolved.
    fn resolve(&mut self, p: &Path) -> Result<PathBuf> {
        let abs = if p.is_absolute() {
            p.to_path_buf()
        } else {
            std::env::current_dir().map_err(|e| Error::io(p, e))?.join(p)
        };
        let name = abs
            .file_name()
            .filter(|n| *n != OsStr::new(".."))
            .map(OsStr::to_os_string)
            .ok_or_else(|| Error::io(p, std::io::Error::other("names no file or folder to write")))?;
        let parent = abs.parent().unwrap_or(Path::new("/")).to_path_buf();
        self.create_dirs(&parent).map_err(|e| Error::io(&parent, e))?;
        let parent = parent.canonicalize().map_err(|e| Error::io(&parent, e))?;
        let joined = parent.join(name);
        // An existing symlinked output folder is staged where it points.
        Ok(if joined.is_dir() { joined.canonicalize().map_err(|e| Error::io(p, e))? } else { joined })
    }

    fn create_dirs(&mut self, dir: &Path) -> std::io::Result<()> {
        let mut missing = Vec::new();
        let mut d = dir;
        while !d.as_os_str().is_empty() && !d.exists() {
            missing.push(d.to_path_buf());
            d = match d.parent() {
                Some(p) => p,
                None => break,
            };
        }
        for m in missing.into_iter().rev() {
            std::fs::create_dir(&m)?;
            self.created.push(m);
        }
        Ok(())
    }

    /// Move everything staged into place: folders first (each in one swap), then files. On an
    /// error nothing that was not yet moved changes, and what is left staged is removed.
    ///
    /// # Errors
    /// [`Error::Io`] naming the output that could not be put in place (for example an old folder
    /// where the new output is a file).
    pub fn commit(mut self) -> Result<()> {
        let dirs = std::mem::take(&mut self.dirs);
        for i in 0..dirs.len() {
            if let Err(e) = commit_dir(&dirs[i]) {
                self.dirs = dirs.into_iter().skip(i).collect();
                return Err(e);
            }
        }
        let files = std::mem::take(&mut self.files);
        for i in 0..files.len() {
            crate::io::hook("commit-file");
            if let Err(e) = std::fs::rename(&files[i].temp, &files[i].target) {
                let err = Error::io(&files[i].target, e);
                self.files = files.into_iter().skip(i).collect();
                return Err(err);
            }
        }
        self.committed = true;
        Ok(())
    }
}

impl Drop for Staging {
    fn drop(&mut self) {
        if self.committed {
            return;
        }
        for g in &self.dirs {
            let _ = remove_tree(&g.stage);
        }
        for f in &self.files {
            let _ = std::fs::remove_file(&f.temp);
        }
        for d in self.created.iter().rev() {
            let _ = std::fs::remove_dir(d); // only if still empty
        }
    }
}

fn file_name(target: &Path, shown: &Path) -> Result<String> {
    target
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .ok_or_else(|| Error::io(shown, std::io::Error::other("names no file or folder to write")))
}

fn commit_dir(g: &DirGroup) -> Result<()> {
    crate::io::hook("carry");
    if !g.target.exists() {
        crate::io::hook("exchange");
        return std::fs::rename(&g.stage, &g.target).map_err(|e| Error::io(&g.target, e));
    }
    carry(&g.target, &g.stage)?;
    if let Ok(meta) = std::fs::metadata(&g.target) {
        let _ = std::fs::set_permissions(&g.stage, meta.permissions());
    }
    crate::io::hook("exchange");
    match exchange(&g.stage, &g.target) {
        Ok(()) => {}
        Err(_) => {
            // Two renames, the old folder parked under a disposable name in between.
            let parked = parked_name(&g.target);
            std::fs::rename(&g.target, &parked).map_err(|e| Error::io(&g.target, e))?;
            if let Err(e) = std::fs::rename(&g.stage, &g.target) {
                let _ = std::fs::rename(&parked, &g.target);
                return Err(Error::io(&g.target, e));
            }
            std::fs::rename(&parked, &g.stage).map_err(|e| Error::io(&parked, e))?;
        }
    }
    crate::io::hook("remove-old");
    // The old folder now sits at the staging name. The new outputs are in place, but a leftover
    // beside them must not pass silently (the next run would carry on around it): say so.
    remove_tree(&g.stage).map_err(|e| {
        Error::io(
            &g.stage,
            std::io::Error::new(
                e.kind(),
                format!(
                    "the new outputs are in {}, but its old contents could not be removed from here: {e}; \
                     remove this folder by hand",
                    g.target.display()
                ),
            ),
        )
    })
}

/// Refuse an output folder whose old contents could not be removed after the swap: the folder or
/// any folder in it without write permission. The permission bits are read directly (no write bit
/// at all is refused even for root, who `access(2)` would let through: a folder made read-only is a
/// request to leave it alone), and `access(W_OK)` covers folders owned by someone else.
/// `shown` is `dir` as the user named it, for the message.
fn check_writable_tree(dir: &Path, shown: &Path) -> Result<()> {
    let meta = std::fs::symlink_metadata(dir).map_err(|e| Error::io(shown, e))?;
    if !meta.is_dir() {
        return Ok(());
    }
    if meta.permissions().readonly() || !writable(dir) {
        return Err(Error::io(
            shown,
            std::io::Error::new(
                std::io::ErrorKind::PermissionDenied,
                format!(
                    "output folder is not writable{}: its old contents could not be replaced; make it \
                     writable (chmod -R u+w) or choose another output folder (nothing was written)",
                    mode_text(&meta)
                ),
            ),
        ));
    }
    for entry in std::fs::read_dir(dir).map_err(|e| Error::io(shown, e))? {
        let entry = entry.map_err(|e| Error::io(shown, e))?;
        let name = entry.file_name();
        if entry.file_type().is_ok_and(|t| t.is_dir()) && !is_disposable(&name.to_string_lossy()) {
            check_writable_tree(&entry.path(), &shown.join(&name))?;
        }
    }
    Ok(())
}

#[cfg(unix)]
fn mode_text(meta: &std::fs::Metadata) -> String {
    use std::os::unix::fs::PermissionsExt;
    format!(" (mode {:04o})", meta.permissions().mode() & 0o7777)
}

#[cfg(not(unix))]
fn mode_text(_meta: &std::fs::Metadata) -> String {
    String::new()
}

#[cfg(unix)]
fn writable(dir: &Path) -> bool {
    use std::os::unix::ffi::OsStrExt;
    let Ok(c) = std::ffi::CString::new(dir.as_os_str().as_bytes()) else { return false };
    // SAFETY: a valid NUL-terminated path; access(2) only reads it.
    unsafe { libc::access(c.as_ptr(), libc::W_OK) == 0 }
}

#[cfg(not(unix))]
fn writable(_dir: &Path) -> bool {
    true
}

/// `remove_dir_all`, retried once after giving every folder inside its owner's write permission
/// (a read-only folder cannot be emptied; ours, or a user's old outputs, may be one).
fn remove_tree(p: &Path) -> std::io::Result<()> {
    match std::fs::remove_dir_all(p) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(_) => {
            make_dirs_writable(p);
            std::fs::remove_dir_all(p)
        }
    }
}

fn make_dirs_writable(p: &Path) {
    let Ok(meta) = std::fs::symlink_metadata(p) else { return };
    if !meta.is_dir() {
        return;
    }
    let mut perms = meta.permissions();
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        perms.set_mode(perms.mode() | 0o700);
    }
    #[cfg(not(unix))]
    perms.set_readonly(false);
    let _ = std::fs::set_permissions(p, perms);
    if let Ok(rd) = std::fs::read_dir(p) {
        for e in rd.flatten() {
            make_dirs_writable(&e.path());
        }
    }
}

fn parked_name(target: &Path) -> PathBuf {
    let name = target.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    target.with_file_name(format!(".{name}{TEMP_MARKER}old-{}", std::process::id()))
}

/// Give the new folder `new` every entry of `old` it does not replace (hard links, copies where a
/// link fails, symlinks recreated), recursing into folders both have.
fn carry(old: &Path, new: &Path) -> Result<()> {
    for entry in std::fs::read_dir(old).map_err(|e| Error::io(old, e))? {
        let entry = entry.map_err(|e| Error::io(old, e))?;
        let name = entry.file_name();
        if is_disposable(&name.to_string_lossy()) {
            continue;
        }
        let (src, dst) = (entry.path(), new.join(&name));
        let kind = entry.file_type().map_err(|e| Error::io(&src, e))?;
        match std::fs::symlink_metadata(&dst) {
            Ok(staged) => {
                if kind.is_dir() && staged.is_dir() {
                    carry(&src, &dst)?;
                } else if kind.is_dir() != staged.is_dir() {
                    let what = if kind.is_dir() { "a folder" } else { "a file" };
                    return Err(Error::io(
                        &src,
                        std::io::Error::other(format!(
                            "is {what} where the new output is not; move it away (nothing was written)"
                        )),
                    ));
                }
            }
            Err(_) => link_or_copy(&src, &dst, kind)?,
        }
    }
    Ok(())
}

fn link_or_copy(src: &Path, dst: &Path, kind: std::fs::FileType) -> Result<()> {
    if kind.is_dir() {
        std::fs::create_dir(dst).map_err(|e| Error::io(dst, e))?;
        return carry(src, dst);
    }
    if kind.is_symlink() {
        let to = std::fs::read_link(src).map_err(|e| Error::io(src, e))?;
        #[cfg(unix)]
        return std::os::unix::fs::symlink(to, dst).map_err(|e| Error::io(dst, e));
        #[cfg(not(unix))]
        {
            let _ = to;
        }
    }
    if std::fs::hard_link(src, dst).is_err() {
        std::fs::copy(src, dst).map_err(|e| Error::io(src, e))?;
    }
    Ok(())
}

/// Swap two folders atomically (Linux `renameat2(RENAME_EXCHANGE)`).
#[cfg(target_os = "linux")]
fn exchange(a: &Path, b: &Path) -> std::io::Result<()> {
    use std::ffi::CString;
    use std::os::unix::ffi::OsStrExt;
    let ca = CString::new(a.as_os_str().as_bytes())?;
    let cb = CString::new(b.as_os_str().as_bytes())?;
    // SAFETY: both are valid NUL-terminated paths; AT_FDCWD with absolute paths; the syscall
    // only reads them.
    let r = unsafe {
        libc::syscall(
            libc::SYS_renameat2,
            libc::AT_FDCWD,
            ca.as_ptr(),
            libc::AT_FDCWD,
            cb.as_ptr(),
            libc::RENAME_EXCHANGE,
        )
    };
    if r == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

#[cfg(not(target_os = "linux"))]
fn exchange(_a: &Path, _b: &Path) -> std::io::Result<()> {
    Err(std::io::Error::from(std::io::ErrorKind::Unsupported))
}

/// The process id in a temporary name of ours (`.X.densefeat-{tmp,stage,old}-PID`, or the
/// `.X.tmp-PID` of earlier versions), if `name` is one.
pub fn temp_owner(name: &str) -> Option<u32> {
    if !name.starts_with('.') {
        return None;
    }
    let (head, pid) = name.rsplit_once('-')?;
    let pid: u32 = pid.parse().ok()?;
    let ours = [".tmp", "densefeat-tmp", "densefeat-stage", "densefeat-old"];
    ours.iter().any(|s| head.ends_with(s)).then_some(pid)
}

/// A temporary of a process that no longer runs.
fn is_disposable(name: &str) -> bool {
    temp_owner(name).is_some_and(|pid| pid != std::process::id() && !process_alive(pid))
}

#[cfg(unix)]
fn process_alive(pid: u32) -> bool {
    let Ok(pid) = libc::pid_t::try_from(pid) else { return false };
    // SAFETY: signal 0 only checks that the process exists.
    let r = unsafe { libc::kill(pid, 0) };
    r == 0 || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM)
}

#[cfg(not(unix))]
fn process_alive(_pid: u32) -> bool {
    true // never remove what might be in use; the names stay obviously disposable
}

/// Remove the temporaries of dead processes directly in `dir` (not recursively); returns how many.
pub fn clean_stale(dir: &Path) -> usize {
    let Ok(rd) = std::fs::read_dir(dir) else { return 0 };
    let mut n = 0;
    for entry in rd.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        if !is_disposable(&name) || name.contains(&format!("{TEMP_MARKER}old-")) {
            continue;
        }
        let p = entry.path();
        let gone = match entry.file_type() {
            Ok(t) if t.is_dir() => remove_tree(&p).is_ok(),
            _ => std::fs::remove_file(&p).is_ok(),
        };
        n += usize::from(gone);
    }
    n
}

/// If a killed run parked the old `parent/name` and died before the new one took its place, put
/// the old one back; otherwise remove parked leftovers.
fn recover_parked(parent: &Path, name: &str) {
    let Ok(rd) = std::fs::read_dir(parent) else { return };
    let prefix = format!(".{name}{TEMP_MARKER}old-");
    let target = parent.join(name);
    for entry in rd.flatten() {
        let n = entry.file_name().to_string_lossy().into_owned();
        if !(n.starts_with(&prefix) && is_disposable(&n)) {
            continue;
        }
        if !target.exists() {
            let _ = std::fs::rename(entry.path(), &target);
        } else {
            let _ = remove_tree(&entry.path());
        }
    }
}
