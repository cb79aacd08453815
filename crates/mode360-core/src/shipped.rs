//! Files that ship with mode360 (the trained weights, the rig calibrations, the parameter file,
//! the Foxglove layout), found wherever the binary runs: from the source tree, after
//! `cargo install`, or copied alone onto a robot.
//!
//! A path such as `launch_configs/rig_deep360.yaml` (every default is one) is looked up in this
//! order, the first file found wins:
//! 1. as given, relative to the working directory (a file of the user's own there wins);
//! 2. under the data directory ([`data_dir`]): `$MODE360_DATA_DIR`, else
//!    `$XDG_DATA_HOME/mode360`, else `$HOME/.local/share/mode360`;
//! 3. beside the binary: `BIN/../share/mode360/` (an install prefix: `cargo install --root DIR`
//!    puts the binary in `DIR/bin`, a package puts the files in `DIR/share/mode360`), then the
//!    binary's own folder;
//! 4. built into the binary: the copy compiled in is written once to
//!    `DATA_DIR/builtin/HASH/PATH` (named by its content, so a newer binary never reads an older
//!    binary's copy) and read from there.
//!
//! Where none of these has it, the path comes back as given, so the caller's "not found" names
//! what was asked for.

use crate::atomic_file::write_atomic;
use std::path::{Path, PathBuf};

/// Environment variable naming the data directory (step 2 of the lookup).
pub const DATA_DIR_ENV: &str = "MODE360_DATA_DIR";
/// Folder under `$XDG_DATA_HOME` (or `$HOME/.local/share`) when [`DATA_DIR_ENV`] is unset.
pub const DATA_DIR_NAME: &str = "mode360";
/// Folder under an install prefix (`BIN/..`) that holds the shipped files.
pub const PREFIX_SHARE_DIR: &str = "share/mode360";
/// Folder of the data directory that holds unpacked built-in copies.
pub const BUILTIN_DIR: &str = "builtin";

/// One file compiled into the binary: its path relative to the repository root (the path the
/// defaults name) and its bytes.
#[derive(Debug, Clone, Copy)]
pub struct BuiltinFile {
    pub relative: &'static str,
    pub bytes: &'static [u8],
}

/// A [`BuiltinFile`] of `path`, relative to the repository root (this file is three folders
/// below it).
macro_rules! builtin {
    ($path:literal) => {
        BuiltinFile {
            relative: $path,
            bytes: include_bytes!(concat!("../../../", $path)),
        }
    };
}

/// The launch configuration the binary carries: the rigs, the node's parameter file, the
/// launch file and the Foxglove layout.
pub const LAUNCH_CONFIGS: &[BuiltinFile] = &[
    builtin!("launch_configs/rig_deep360.yaml"),
    builtin!("launch_configs/rig_omnimvs.yaml"),
    builtin!("launch_configs/rig_dual_fisheye.yaml"),
    builtin!("launch_configs/mode360.params.yaml"),
    builtin!("launch_configs/mode360.launch.xml"),
    builtin!("launch_configs/foxglove_layout.json"),
];

/// Where a located file was found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Origin {
    /// As given (relative to the working directory, or absolute).
    AsGiven,
    /// Under the data directory.
    DataDir,
    /// Beside the binary (its install prefix or its folder).
    BesideBinary,
    /// The copy built into the binary, unpacked into the data directory.
    Builtin,
    /// Nowhere: the path as given, which does not exist.
    NotFound,
}

/// A located file: its path and where it was found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Located {
    pub path: PathBuf,
    pub origin: Origin,
}

/// The data directory: `$MODE360_DATA_DIR`, else `$XDG_DATA_HOME/mode360`, else
/// `$HOME/.local/share/mode360`, else `mode360` under the system's temporary folder.
pub fn data_dir() -> PathBuf {
    let set = |name: &str| std::env::var_os(name).filter(|v| !v.is_empty());
    if let Some(dir) = set(DATA_DIR_ENV) {
        return PathBuf::from(dir);
    }
    if let Some(xdg) = set("XDG_DATA_HOME") {
        return PathBuf::from(xdg).join(DATA_DIR_NAME);
    }
    if let Some(home) = set("HOME") {
        return PathBuf::from(home).join(".local/share").join(DATA_DIR_NAME);
    }
    std::env::temp_dir().join(DATA_DIR_NAME)
}

/// The folders searched beside the running binary: `BIN/../share/mode360` and `BIN`'s own.
pub fn beside_binary_dirs() -> Vec<PathBuf> {
    let Some(dir) = std::env::current_exe()
        .ok()
        .and_then(|exe| exe.parent().map(Path::to_path_buf))
    else {
        return Vec::new();
    };
    let mut dirs = Vec::new();
    if let Some(prefix) = dir.parent() {
        dirs.push(prefix.join(PREFIX_SHARE_DIR));
    }
    dirs.push(dir);
    dirs
}

/// Looks `path` up in the order of the module docs; `builtin` holds the copies compiled in.
/// A path that exists as given, or an absolute one, comes back unchanged.
pub fn locate(path: &Path, builtin: &[BuiltinFile]) -> Located {
    let found = |path: PathBuf, origin| Located { path, origin };
    if path.is_file() {
        return found(path.to_path_buf(), Origin::AsGiven);
    }
    if path.is_absolute() {
        return found(path.to_path_buf(), Origin::NotFound);
    }
    let data = data_dir();
    let in_data = data.join(path);
    if in_data.is_file() {
        return found(in_data, Origin::DataDir);
    }
    for dir in beside_binary_dirs() {
        let beside = dir.join(path);
        if beside.is_file() {
            return found(beside, Origin::BesideBinary);
        }
    }
    let wanted = normalized(path);
    if let Some(file) = builtin.iter().find(|f| Path::new(f.relative) == wanted) {
        if let Some(unpacked) =
            unpack(file, &data).or_else(|| unpack(file, &std::env::temp_dir().join(DATA_DIR_NAME)))
        {
            return found(unpacked, Origin::Builtin);
        }
    }
    found(path.to_path_buf(), Origin::NotFound)
}

/// [`locate`]'s path alone.
pub fn locate_path(path: &Path, builtin: &[BuiltinFile]) -> PathBuf {
    locate(path, builtin).path
}

/// `path` without `.` components (`./models/x` names the same built-in file as `models/x`).
fn normalized(path: &Path) -> PathBuf {
    path.components()
        .filter(|c| !matches!(c, std::path::Component::CurDir))
        .collect()
}

/// Writes `file` to `data/builtin/HASH/RELATIVE` unless a copy with the same bytes is there;
/// None when it cannot be written.
fn unpack(file: &BuiltinFile, data: &Path) -> Option<PathBuf> {
    let target = data
        .join(BUILTIN_DIR)
        .join(format!("{:016x}", content_hash(file.bytes)))
        .join(file.relative);
    let current = std::fs::read(&target).is_ok_and(|bytes| bytes == file.bytes);
    if current {
        return Some(target);
    }
    std::fs::create_dir_all(target.parent()?).ok()?;
    write_atomic(&target, file.bytes).ok()?;
    Some(target)
}

/// FNV-1a over `bytes`: names a built-in copy by its content.
fn content_hash(bytes: &[u8]) -> u64 {
    const OFFSET_BASIS: u64 = 0xcbf2_9ce4_8422_2325;
    const PRIME: u64 = 0x0000_0100_0000_01b3;
    bytes
        .iter()
        .fold(OFFSET_BASIS, |h, &b| (h ^ u64::from(b)).wrapping_mul(PRIME))
}

#[cfg(test)]
mod tests {
    use super::*;

    const TEXT: BuiltinFile = BuiltinFile {
        relative: "configs/thing.yaml",
        bytes: b"answer: 42\n",
    };

    /// The lookup of one data directory, without touching the process's environment: the
    /// steps `locate` takes after "as given" with `data` as the data directory.
    fn unpacked_in(data: &Path) -> PathBuf {
        unpack(&TEXT, data).expect("writable")
    }

    #[test]
    fn builtin_copy_is_unpacked_once_by_content() {
        let dir = std::env::temp_dir().join(format!("mode360_shipped_{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let first = unpacked_in(&dir);
        assert!(first.starts_with(dir.join(BUILTIN_DIR)));
        assert!(first.ends_with(TEXT.relative));
        assert_eq!(std::fs::read(&first).unwrap(), TEXT.bytes);
        // A damaged copy is rewritten; the same content lands on the same path.
        std::fs::write(&first, b"answer: 41\n").unwrap();
        assert_eq!(unpacked_in(&dir), first);
        assert_eq!(std::fs::read(&first).unwrap(), TEXT.bytes);
        // Other bytes under the same name land elsewhere (a newer binary's copy).
        let newer = BuiltinFile {
            relative: TEXT.relative,
            bytes: b"answer: 43\n",
        };
        let second = unpack(&newer, &dir).unwrap();
        assert_ne!(second, first);
        assert_eq!(std::fs::read(&first).unwrap(), TEXT.bytes);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn existing_and_absolute_paths_are_not_searched() {
        let manifest = Path::new(env!("CARGO_MANIFEST_DIR")).join("Cargo.toml");
        let got = locate(&manifest, LAUNCH_CONFIGS);
        assert_eq!(
            (got.path.as_path(), got.origin),
            (manifest.as_path(), Origin::AsGiven)
        );
        let missing = Path::new("/nonexistent/launch_configs/rig_deep360.yaml");
        assert_eq!(locate(missing, LAUNCH_CONFIGS).origin, Origin::NotFound);
    }

    #[test]
    fn unknown_relative_path_is_not_found_as_given() {
        let path = Path::new("no_such_folder_mode360/nothing.yaml");
        let got = locate(path, LAUNCH_CONFIGS);
        assert_eq!((got.path.as_path(), got.origin), (path, Origin::NotFound));
    }

    #[test]
    fn builtin_rig_matches_the_source_tree() {
        let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        for file in LAUNCH_CONFIGS {
            let on_disk = std::fs::read(repo.join(file.relative)).unwrap();
            assert_eq!(on_disk, file.bytes, "{}", file.relative);
        }
        assert_eq!(normalized(Path::new("./a/./b")), Path::new("a/b"));
    }
}
