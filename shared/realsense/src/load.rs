//! Finding and loading librealsense2 at run time.
//!
//! Where the library comes from, in order: a configured path, `$PSGRASP_REALSENSE_LIB`, a system
//! `librealsense2.so`, and the `pyrealsense2` wheel of the project's Python venv, whose extension
//! module exports librealsense's C API (it needs the Python runtime's symbols, so its
//! `libpython3.X.so` is loaded first, with `RTLD_GLOBAL`).
use crate::ffi::Api;
use crate::Error;
use libloading::os::unix::{Library as DynLib, RTLD_GLOBAL, RTLD_NOW};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};

/// Environment variable naming the library (a `librealsense2.so` or `pyrealsense2*.so`).
pub const LIBRARY_ENV: &str = "PSGRASP_REALSENSE_LIB";
/// The project's venv (as in `scripts/setup-python.sh`); default `~/.cache/psgrasp-venv`.
pub const VENV_ENV: &str = "PSGRASP_VENV";
/// The venv's Python (`scripts/test.sh` sets it); its venv is searched too.
pub const PYTHON_ENV: &str = "PSGRASP_PYTHON";
/// Folders searched for a system `librealsense2.so.2.*`.
pub const SYSTEM_DIRS: [&str; 5] = [
    "/usr/local/lib",
    "/usr/local/lib64",
    "/usr/lib/x86_64-linux-gnu",
    "/usr/lib/aarch64-linux-gnu",
    "/usr/lib",
];
/// How to get the library, appended to "not found" errors.
pub const INSTALL_HINT: &str = "install the pyrealsense2 wheel into the project's venv \
    (scripts/setup-python.sh does; training/requirements.txt pins it) or librealsense2 \
    (https://github.com/IntelRealSense/librealsense), or name the library in \
    camera.realsense.library or $PSGRASP_REALSENSE_LIB";

/// A loaded librealsense2: its functions, version and file. Loaded libraries stay loaded for
/// the life of the process (librealsense keeps threads that must not outlive its code).
pub struct Library {
    pub(crate) api: Api,
    version: i32,
    path: PathBuf,
}

impl std::fmt::Debug for Library {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "librealsense {} ({})",
            self.version(),
            self.path.display()
        )
    }
}

impl Library {
    /// Finds and loads the library (see the module docs for the order); `configured`, when
    /// given, is the only candidate, as is `$PSGRASP_REALSENSE_LIB` when set.
    pub fn load(configured: Option<&Path>) -> Result<&'static Library, Error> {
        let explicit = configured
            .map(Path::to_path_buf)
            .or_else(|| std::env::var_os(LIBRARY_ENV).map(PathBuf::from))
            .filter(|p| !p.as_os_str().is_empty());
        let mut tried = Vec::new();
        let candidates = match explicit {
            Some(p) => vec![p],
            None => search_candidates(&mut tried),
        };
        for path in candidates {
            // A bare name is looked up by the dynamic loader (LD_LIBRARY_PATH, ld.so.cache).
            if path.components().count() > 1 && !path.is_file() {
                tried.push(path.display().to_string());
                continue;
            }
            match Self::load_file(&path) {
                Err(Error::Load { reason, .. })
                    if path.components().count() == 1
                        && reason.contains(&format!("{}: cannot open", path.display())) =>
                {
                    tried.push(format!("{} (not on the loader's path)", path.display()));
                }
                result => return result,
            }
        }
        Err(Error::NotFound { tried })
    }

    /// Loads the library at `path` (cached: a second call returns the same library).
    pub fn load_file(path: &Path) -> Result<&'static Library, Error> {
        static LOADED: OnceLock<Mutex<HashMap<PathBuf, &'static Library>>> = OnceLock::new();
        let mut loaded = LOADED
            .get_or_init(Default::default)
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        if let Some(lib) = loaded.get(path) {
            return Ok(lib);
        }
        let fail = |reason: String| Error::Load {
            path: path.to_path_buf(),
            reason,
        };
        if let Some(python) = python_module_version(path) {
            load_libpython(path, &python).map_err(fail)?;
        }
        // SAFETY: librealsense's initialisers only set up its own state.
        let dynlib = unsafe { DynLib::open(Some(path), RTLD_NOW | RTLD_GLOBAL) }
            .map_err(|e| fail(dl_error(&e)))?;
        // SAFETY: the library exports librealsense's C API with the declared signatures.
        let api = unsafe { Api::resolve(&dynlib) }.map_err(fail)?;
        let mut err = std::ptr::null_mut();
        // SAFETY: a plain call with an error out-pointer.
        let version = unsafe { (api.rs2_get_api_version)(&mut err) };
        crate::check(&api, err).map_err(|e| fail(e.to_string()))?;
        // Never unloaded (see `Library`).
        std::mem::forget(dynlib);
        let lib: &'static Library = Box::leak(Box::new(Library {
            api,
            version,
            path: path.to_path_buf(),
        }));
        loaded.insert(path.to_path_buf(), lib);
        Ok(lib)
    }

    /// The API version as `major.minor.patch`, e.g. `2.59.1`.
    pub fn version(&self) -> String {
        let v = self.version;
        format!("{}.{}.{}", v / 10000, (v / 100) % 100, v % 100)
    }

    /// The API version number (`major * 10000 + minor * 100 + patch`).
    pub fn api_version(&self) -> i32 {
        self.version
    }

    /// The file it was loaded from.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// System libraries first (newest version first), then the venvs' `pyrealsense2` modules;
/// places searched without a match are added to `tried`.
fn search_candidates(tried: &mut Vec<String>) -> Vec<PathBuf> {
    let mut out: Vec<PathBuf> = Vec::new();
    for dir in SYSTEM_DIRS {
        let mut found = list(Path::new(dir), |n| n.starts_with("librealsense2.so.2."));
        if found.is_empty() {
            tried.push(format!("{dir}/librealsense2.so.2.*"));
        }
        found.sort();
        out.extend(found.into_iter().rev());
    }
    out.push(PathBuf::from("librealsense2.so"));
    for venv in venvs() {
        let mut found: Vec<PathBuf> = list(&venv.join("lib"), |n| n.starts_with("python3"))
            .into_iter()
            .flat_map(|py| {
                list(&py.join("site-packages/pyrealsense2"), |n| {
                    n.starts_with("pyrealsense2.cpython-") && n.ends_with(".so")
                })
            })
            .collect();
        if found.is_empty() {
            tried.push(format!(
                "{}/lib/python3*/site-packages/pyrealsense2/pyrealsense2.cpython-*.so",
                venv.display()
            ));
        }
        found.sort();
        out.extend(found);
    }
    out.dedup();
    out
}

/// `$PSGRASP_VENV`, the venv of `$PSGRASP_PYTHON`, and `~/.cache/psgrasp-venv`.
fn venvs() -> Vec<PathBuf> {
    let mut out = Vec::new();
    if let Some(v) = std::env::var_os(VENV_ENV) {
        out.push(PathBuf::from(v));
    }
    if let Some(py) = std::env::var_os(PYTHON_ENV) {
        if let Some(venv) = Path::new(&py).parent().and_then(Path::parent) {
            out.push(venv.to_path_buf());
        }
    }
    if let Some(home) = std::env::var_os("HOME") {
        out.push(Path::new(&home).join(".cache/psgrasp-venv"));
    }
    out.dedup();
    out
}

/// Entries of `dir` whose file name passes `keep` (none when `dir` cannot be read).
fn list(dir: &Path, keep: impl Fn(&str) -> bool) -> Vec<PathBuf> {
    std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_str().is_some_and(&keep))
        .map(|e| e.path())
        .collect()
}

/// The loader's own message (libloading's error keeps it as its source).
pub(crate) fn dl_error(e: &libloading::Error) -> String {
    let mut text = e.to_string();
    let mut source = std::error::Error::source(e);
    while let Some(s) = source {
        text = s.to_string();
        source = s.source();
    }
    text
}

/// `3.11` for `pyrealsense2.cpython-311-x86_64-linux-gnu.so`; `None` for other files.
fn python_module_version(path: &Path) -> Option<String> {
    let name = path.file_name()?.to_str()?;
    let tag = name
        .strip_prefix("pyrealsense2.cpython-")?
        .split('-')
        .next()?;
    let (major, minor) = tag.split_at_checked(1)?;
    (major == "3" && minor.parse::<u32>().is_ok()).then(|| format!("{major}.{minor}"))
}

/// Loads `libpython<version>.so` globally, so a `pyrealsense2` module finds the symbols of the
/// Python runtime it was built for: the venv's interpreter's (`home` in its `pyvenv.cfg`),
/// then the loader's.
fn load_libpython(module: &Path, version: &str) -> Result<(), String> {
    let names = [
        format!("libpython{version}.so.1.0"),
        format!("libpython{version}.so"),
    ];
    let mut candidates: Vec<PathBuf> = Vec::new();
    let venv_cfg = module.ancestors().find_map(|d| {
        let cfg = d.join("pyvenv.cfg");
        std::fs::read_to_string(cfg).ok()
    });
    if let Some(home) = venv_cfg.as_deref().and_then(|cfg| {
        cfg.lines()
            .filter_map(|l| l.split_once('='))
            .find(|(k, _)| k.trim() == "home")
            .map(|(_, v)| PathBuf::from(v.trim()))
    }) {
        let lib = home.parent().map(|p| p.join("lib")).unwrap_or_default();
        candidates.extend(names.iter().map(|n| lib.join(n)));
    }
    candidates.extend(names.iter().map(PathBuf::from));
    let mut errors = Vec::new();
    for c in &candidates {
        if c.components().count() > 1 && !c.is_file() {
            errors.push(format!("{} (no such file)", c.display()));
            continue;
        }
        // SAFETY: loading libpython runs no Python code.
        match unsafe { DynLib::open(Some(c), RTLD_NOW | RTLD_GLOBAL) } {
            Ok(lib) => {
                // Stays loaded: the module's symbols point into it.
                std::mem::forget(lib);
                return Ok(());
            }
            Err(e) => errors.push(dl_error(&e)),
        }
    }
    Err(format!(
        "the pyrealsense2 module needs the Python {version} runtime library, not found: {}",
        errors.join("; ")
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn python_tags_are_read_from_module_names() {
        let v = |n: &str| python_module_version(Path::new(n));
        assert_eq!(
            v("/x/pyrealsense2.cpython-311-x86_64-linux-gnu.so").as_deref(),
            Some("3.11")
        );
        assert_eq!(
            v("pyrealsense2.cpython-39-aarch64-linux-gnu.so").as_deref(),
            Some("3.9")
        );
        assert_eq!(v("librealsense2.so.2.59.1"), None);
        assert_eq!(v("pyrealsense2.cpython-.so"), None);
    }
}
