//! The `.fmu` file: `modelDescription.xml`, the shared library for each platform given, and
//! the config and variant in `resources/` (FMI 2.0 §2.3: the FMU's zip layout).

use crate::variables::Variant;
use crate::MODEL_IDENTIFIER;
use ehactl_config::RigConfig;
use std::path::{Path, PathBuf};

/// The FMU's platform directory of the machine this runs on (`linux64` for x86-64 Linux,
/// FMI 2.0 §2.3; `aarch64-linux` as FMI 3.0 §2.5.1.4 names it, which FMI 2.0 does not list).
pub fn native_platform() -> &'static str {
    if cfg!(target_arch = "aarch64") {
        "aarch64-linux"
    } else {
        "linux64"
    }
}

/// What to export.
pub struct Export<'a> {
    /// The config's text (TOML), as written into `resources/config.toml`.
    pub config_text: &'a str,
    /// Plant or closed loop.
    pub variant: Variant,
    /// The shared libraries by FMU platform directory (`linux64`, `aarch64-linux`).
    pub binaries: Vec<(String, PathBuf)>,
}

/// The FMU file's bytes. The config must load (its errors name the field); every library
/// must be readable.
pub fn fmu_bytes(e: &Export<'_>) -> Result<Vec<u8>, String> {
    let cfg = RigConfig::from_toml_str(e.config_text).map_err(|err| err.to_string())?;
    let md = crate::xml::model_description(&cfg, e.config_text, e.variant);
    let mut libs = Vec::new();
    for (platform, path) in &e.binaries {
        let bytes = std::fs::read(path).map_err(|err| {
            format!(
                "cannot read the FMU library {} ({platform}): {err}",
                path.display()
            )
        })?;
        libs.push((format!("binaries/{platform}/{MODEL_IDENTIFIER}.so"), bytes));
    }
    let mut entries: Vec<(&str, &[u8])> = vec![
        ("modelDescription.xml", md.as_bytes()),
        ("resources/config.toml", e.config_text.as_bytes()),
        ("resources/variant", e.variant.as_str().as_bytes()),
    ];
    for (name, bytes) in &libs {
        entries.push((name, bytes));
    }
    crate::zip::stored(&entries)
}

/// Write the FMU to `out` (through a temporary file beside it, renamed into place).
pub fn write_fmu(e: &Export<'_>, out: &Path) -> Result<(), String> {
    let bytes = fmu_bytes(e)?;
    let tmp = out.with_extension("fmu.part");
    std::fs::write(&tmp, &bytes).map_err(|err| format!("cannot write {}: {err}", tmp.display()))?;
    std::fs::rename(&tmp, out).map_err(|err| {
        let _ = std::fs::remove_file(&tmp);
        format!("cannot write {}: {err}", out.display())
    })
}
