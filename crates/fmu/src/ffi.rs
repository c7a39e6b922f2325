//! The FMI 2.0 co-simulation C API (FMI 2.0, Modelica Association 2014, §2.1 and §4.2),
//! written by hand. Why by hand: the maintained Rust FMI export crate, rust-fmi's
//! `fmi-export`, generates FMI 3.0 only, and from a model struct whose variables are fixed at
//! compile time; this library is one binary for every config, whose variables come from the
//! config in the FMU's resources at instantiate (docs/fmu.md). No crate exports FMI 2.0.
//!
//! Every function catches panics (`std::panic::catch_unwind`): a panic never unwinds into
//! the host; it returns fmi2Fatal with the message sent to the host's logger. Refused calls
//! and inputs return fmi2Error with their reason logged under `logStatusError`. The instance
//! lives behind the `fmi2Component` pointer (a `Box<Component>`); there is no global state.

use crate::instance::{read_resources, Instance};
use crate::variables::Value;
use std::ffi::{c_char, c_int, c_uint, c_void, CStr, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};

/// fmi2Status.
type Status = c_int;
const OK: Status = 0;
const WARNING: Status = 1;
const ERROR: Status = 3;
const FATAL: Status = 4;

/// fmi2CallbackLogger: `(env, instanceName, status, category, message, ...)`, printf-style.
type Logger =
    unsafe extern "C" fn(*mut c_void, *const c_char, Status, *const c_char, *const c_char, ...);

/// fmi2CallbackFunctions (FMI 2.0 §2.1.5).
#[repr(C)]
pub struct Callbacks {
    logger: Option<Logger>,
    allocate_memory: Option<unsafe extern "C" fn(usize, usize) -> *mut c_void>,
    free_memory: Option<unsafe extern "C" fn(*mut c_void)>,
    step_finished: Option<unsafe extern "C" fn(*mut c_void, Status)>,
    component_environment: *mut c_void,
}

/// What the C side holds behind an `fmi2Component`.
pub struct Component {
    name: CString,
    logger: Option<Logger>,
    env: *mut c_void,
    logging_on: bool,
    inst: Instance,
}

/// Send `msg` to the host's logger with `status` and `category`. The message is the
/// logger's format argument with every `%` doubled: a host that formats it (printf-style, as
/// FMI 2.0 §2.1.5 allows) prints it as written, and one that does not (FMPy's ctypes logger)
/// shows it as is, but for `%%`.
fn log_to(
    logger: Option<Logger>,
    env: *mut c_void,
    name: &CStr,
    status: Status,
    cat: &str,
    msg: &str,
) {
    let Some(f) = logger else { return };
    let cat = CString::new(cat).unwrap_or_default();
    let msg = CString::new(msg.replace('\0', " ").replace('%', "%%")).unwrap_or_default();
    // SAFETY: the host gave this logger for this instance; all strings are NUL-terminated
    // and live across the call; the format has no conversion left (every `%` is doubled).
    unsafe { f(env, name.as_ptr(), status, cat.as_ptr(), msg.as_ptr()) };
}

impl Component {
    fn log(&self, status: Status, cat: &str, msg: &str) {
        if status >= ERROR || self.logging_on {
            log_to(self.logger, self.env, &self.name, status, cat, msg);
        }
    }

    /// Log the error of `r` and map it to its status.
    fn status(&mut self, r: Result<(), String>) -> Status {
        let events = std::mem::take(&mut self.inst.events);
        for e in &events {
            log_to(self.logger, self.env, &self.name, WARNING, "logEvents", e);
        }
        match r {
            Ok(()) => OK,
            Err(e) => {
                self.log(ERROR, "logStatusError", &e);
                ERROR
            }
        }
    }
}

/// Run `f` on the component behind `c`, catching a panic (fmi2Fatal, logged).
fn with(c: *mut c_void, f: impl FnOnce(&mut Component) -> Status) -> Status {
    if c.is_null() {
        return ERROR;
    }
    // SAFETY: `c` is a pointer fmi2Instantiate returned (a leaked Box<Component>) and not
    // yet freed; FMI 2.0 §2.1.2 forbids concurrent calls on one instance.
    let comp = unsafe { &mut *(c as *mut Component) };
    match catch_unwind(AssertUnwindSafe(|| f(comp))) {
        Ok(s) => s,
        Err(p) => {
            // SAFETY: as above; the closure that borrowed the component has ended.
            let comp = unsafe { &*(c as *const Component) };
            let (logger, env, name) = (comp.logger, comp.env, &comp.name);
            let what = p
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| p.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "panic".into());
            log_to(
                logger,
                env,
                name,
                FATAL,
                "logStatusError",
                &format!("internal error: {what}"),
            );
            FATAL
        }
    }
}

/// The C string `s` (empty when null).
fn text(s: *const c_char) -> String {
    if s.is_null() {
        return String::new();
    }
    // SAFETY: FMI strings are NUL-terminated and valid for the call.
    unsafe { CStr::from_ptr(s) }.to_string_lossy().into_owned()
}

/// The directory of an `fmuResourceLocation` URI (`file:///…`, `file:/…`, percent-escaped).
fn resource_dir(uri: &str) -> Result<std::path::PathBuf, String> {
    let path = uri
        .strip_prefix("file://localhost/")
        .map(|p| format!("/{p}"))
        .or_else(|| uri.strip_prefix("file://").map(str::to_string))
        .or_else(|| uri.strip_prefix("file:").map(str::to_string))
        .ok_or_else(|| {
            format!(
                "fmuResourceLocation `{uri}` is no file URI; expected file:///path/to/resources"
            )
        })?;
    let b = path.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' && i + 2 < b.len() {
            if let Ok(v) = u8::from_str_radix(&path[i + 1..i + 3], 16) {
                out.push(v);
                i += 3;
                continue;
            }
        }
        out.push(b[i]);
        i += 1;
    }
    use std::os::unix::ffi::OsStringExt;
    Ok(std::ffi::OsString::from_vec(out).into())
}

/// The component for fmi2Instantiate's arguments, or the reason it cannot be made.
fn instantiate(name: &CStr, kind: c_int, guid: &str, resources: &str) -> Result<Instance, String> {
    if kind != 1 {
        return Err(format!(
            "fmuType {kind} requested; this FMU is co-simulation only (fmi2CoSimulation = 1)"
        ));
    }
    let dir = resource_dir(resources)?;
    let (text, variant) = read_resources(&dir)?;
    let _ = name;
    Instance::new(&text, variant, guid)
}

/// fmi2Instantiate.
///
/// # Safety
/// The arguments as FMI 2.0 §2.1.5 defines them.
#[no_mangle]
pub unsafe extern "C" fn fmi2Instantiate(
    instance_name: *const c_char,
    fmu_type: c_int,
    guid: *const c_char,
    resource_location: *const c_char,
    functions: *const Callbacks,
    _visible: c_int,
    logging_on: c_int,
) -> *mut c_void {
    let r = catch_unwind(|| {
        let name = CString::new(text(instance_name)).unwrap_or_default();
        // SAFETY: the host passes a valid fmi2CallbackFunctions (or null).
        let (logger, env) = unsafe { functions.as_ref() }
            .map_or((None, std::ptr::null_mut()), |f| {
                (f.logger, f.component_environment)
            });
        match instantiate(&name, fmu_type, &text(guid), &text(resource_location)) {
            Ok(inst) => Box::into_raw(Box::new(Component {
                name,
                logger,
                env,
                logging_on: logging_on != 0,
                inst,
            })) as *mut c_void,
            Err(e) => {
                log_to(logger, env, &name, ERROR, "logStatusError", &e);
                std::ptr::null_mut()
            }
        }
    });
    r.unwrap_or(std::ptr::null_mut())
}

/// fmi2FreeInstance.
///
/// # Safety
/// `c` from fmi2Instantiate, freed once.
#[no_mangle]
pub unsafe extern "C" fn fmi2FreeInstance(c: *mut c_void) {
    if !c.is_null() {
        // SAFETY: a Box<Component> fmi2Instantiate leaked; the host frees it once.
        let _ = catch_unwind(|| drop(unsafe { Box::from_raw(c as *mut Component) }));
    }
}

/// fmi2GetTypesPlatform.
#[no_mangle]
pub extern "C" fn fmi2GetTypesPlatform() -> *const c_char {
    c"default".as_ptr()
}

/// fmi2GetVersion.
#[no_mangle]
pub extern "C" fn fmi2GetVersion() -> *const c_char {
    c"2.0".as_ptr()
}

/// fmi2SetDebugLogging: logging on or off (the categories are not filtered further).
///
/// # Safety
/// FMI 2.0 arguments.
#[no_mangle]
pub unsafe extern "C" fn fmi2SetDebugLogging(
    c: *mut c_void,
    on: c_int,
    _n: usize,
    _cats: *const *const c_char,
) -> Status {
    with(c, |comp| {
        comp.logging_on = on != 0;
        OK
    })
}

/// fmi2SetupExperiment.
///
/// # Safety
/// FMI 2.0 arguments.
#[no_mangle]
pub unsafe extern "C" fn fmi2SetupExperiment(
    c: *mut c_void,
    _tol_defined: c_int,
    _tol: f64,
    start: f64,
    _stop_defined: c_int,
    _stop: f64,
) -> Status {
    with(c, |comp| {
        let r = comp.inst.setup(start);
        comp.status(r)
    })
}

/// fmi2EnterInitializationMode.
///
/// # Safety
/// FMI 2.0 arguments.
#[no_mangle]
pub unsafe extern "C" fn fmi2EnterInitializationMode(c: *mut c_void) -> Status {
    with(c, |comp| {
        let r = comp.inst.enter_init();
        comp.status(r)
    })
}

/// fmi2ExitInitializationMode.
///
/// # Safety
/// FMI 2.0 arguments.
#[no_mangle]
pub unsafe extern "C" fn fmi2ExitInitializationMode(c: *mut c_void) -> Status {
    with(c, |comp| {
        let r = comp.inst.exit_init();
        comp.status(r)
    })
}

/// fmi2Terminate.
///
/// # Safety
/// FMI 2.0 arguments.
#[no_mangle]
pub unsafe extern "C" fn fmi2Terminate(c: *mut c_void) -> Status {
    with(c, |comp| {
        let r = comp.inst.terminate();
        comp.status(r)
    })
}

/// fmi2Reset.
///
/// # Safety
/// FMI 2.0 arguments.
#[no_mangle]
pub unsafe extern "C" fn fmi2Reset(c: *mut c_void) -> Status {
    with(c, |comp| {
        comp.inst.reset();
        OK
    })
}

/// The `n` value references at `vr` (empty when null or 0).
fn refs<'a>(vr: *const c_uint, n: usize) -> &'a [c_uint] {
    if vr.is_null() || n == 0 {
        return &[];
    }
    // SAFETY: the host passes `n` value references.
    unsafe { std::slice::from_raw_parts(vr, n) }
}

/// Get `n` values through `put(i, value)`.
fn get_values(
    c: *mut c_void,
    vr: *const c_uint,
    n: usize,
    out_is_null: bool,
    mut put: impl FnMut(usize, Value) -> Result<(), String>,
) -> Status {
    with(c, |comp| {
        if out_is_null && n > 0 {
            return comp.status(Err("null value array".into()));
        }
        let mut r = Ok(());
        for (i, &v) in refs(vr, n).iter().enumerate() {
            r = comp.inst.get(v).and_then(|x| put(i, x));
            if r.is_err() {
                break;
            }
        }
        comp.status(r)
    })
}

/// Set `n` values read by `take(i)`.
fn set_values(
    c: *mut c_void,
    vr: *const c_uint,
    n: usize,
    in_is_null: bool,
    take: impl Fn(usize) -> Value,
) -> Status {
    with(c, |comp| {
        if in_is_null && n > 0 {
            return comp.status(Err("null value array".into()));
        }
        let mut r = Ok(());
        for (i, &v) in refs(vr, n).iter().enumerate() {
            r = comp.inst.set(v, take(i));
            if r.is_err() {
                break;
            }
        }
        comp.status(r)
    })
}

fn wrong(expected: &str, got: Value) -> String {
    format!("the variable is {got:?}-typed; it was read as {expected}")
}

/// fmi2GetReal.
///
/// # Safety
/// FMI 2.0 arguments: `value` holds `n` entries.
#[no_mangle]
pub unsafe extern "C" fn fmi2GetReal(
    c: *mut c_void,
    vr: *const c_uint,
    n: usize,
    value: *mut f64,
) -> Status {
    get_values(c, vr, n, value.is_null(), |i, x| match x {
        // SAFETY: `value` holds `n` > i entries.
        Value::Real(r) => {
            unsafe { *value.add(i) = r };
            Ok(())
        }
        other => Err(wrong("Real", other)),
    })
}

/// fmi2GetInteger.
///
/// # Safety
/// FMI 2.0 arguments: `value` holds `n` entries.
#[no_mangle]
pub unsafe extern "C" fn fmi2GetInteger(
    c: *mut c_void,
    vr: *const c_uint,
    n: usize,
    value: *mut c_int,
) -> Status {
    get_values(c, vr, n, value.is_null(), |i, x| match x {
        // SAFETY: `value` holds `n` > i entries.
        Value::Integer(v) => {
            unsafe { *value.add(i) = v as c_int };
            Ok(())
        }
        other => Err(wrong("Integer", other)),
    })
}

/// fmi2GetBoolean.
///
/// # Safety
/// FMI 2.0 arguments: `value` holds `n` entries.
#[no_mangle]
pub unsafe extern "C" fn fmi2GetBoolean(
    c: *mut c_void,
    vr: *const c_uint,
    n: usize,
    value: *mut c_int,
) -> Status {
    get_values(c, vr, n, value.is_null(), |i, x| match x {
        // SAFETY: `value` holds `n` > i entries.
        Value::Boolean(b) => {
            unsafe { *value.add(i) = c_int::from(b) };
            Ok(())
        }
        other => Err(wrong("Boolean", other)),
    })
}

/// fmi2SetReal.
///
/// # Safety
/// FMI 2.0 arguments: `value` holds `n` entries.
#[no_mangle]
pub unsafe extern "C" fn fmi2SetReal(
    c: *mut c_void,
    vr: *const c_uint,
    n: usize,
    value: *const f64,
) -> Status {
    // SAFETY: `value` holds `n` > i entries.
    set_values(c, vr, n, value.is_null(), |i| {
        Value::Real(unsafe { *value.add(i) })
    })
}

/// fmi2SetInteger.
///
/// # Safety
/// FMI 2.0 arguments: `value` holds `n` entries.
#[no_mangle]
pub unsafe extern "C" fn fmi2SetInteger(
    c: *mut c_void,
    vr: *const c_uint,
    n: usize,
    value: *const c_int,
) -> Status {
    // SAFETY: `value` holds `n` > i entries.
    set_values(c, vr, n, value.is_null(), |i| {
        Value::Integer(i64::from(unsafe { *value.add(i) }))
    })
}

/// fmi2SetBoolean.
///
/// # Safety
/// FMI 2.0 arguments: `value` holds `n` entries.
#[no_mangle]
pub unsafe extern "C" fn fmi2SetBoolean(
    c: *mut c_void,
    vr: *const c_uint,
    n: usize,
    value: *const c_int,
) -> Status {
    // SAFETY: `value` holds `n` > i entries.
    set_values(c, vr, n, value.is_null(), |i| {
        Value::Boolean(unsafe { *value.add(i) } != 0)
    })
}

/// fmi2DoStep.
///
/// # Safety
/// FMI 2.0 arguments.
#[no_mangle]
pub unsafe extern "C" fn fmi2DoStep(c: *mut c_void, t: f64, h: f64, _no_prior: c_int) -> Status {
    with(c, |comp| {
        let r = comp.inst.do_step(t, h);
        comp.status(r)
    })
}

/// Refuse a call this FMU does not support (its capability flag is false), logged.
fn unsupported(c: *mut c_void, what: &str) -> Status {
    with(c, |comp| {
        comp.status(Err(format!(
            "{what} is not supported by this FMU (see its capability flags)"
        )))
    })
}

macro_rules! refused {
    ($($name:ident($($arg:ident: $ty:ty),*);)*) => {$(
        /// Not supported (its capability flag in the model description is false): fmi2Error.
        ///
        /// # Safety
        /// FMI 2.0 arguments.
        #[no_mangle]
        pub unsafe extern "C" fn $name(c: *mut c_void, $($arg: $ty),*) -> Status {
            $(let _ = $arg;)*
            unsupported(c, stringify!($name))
        }
    )*};
}

refused! {
    fmi2GetString(vr: *const c_uint, n: usize, value: *mut *const c_char);
    fmi2SetString(vr: *const c_uint, n: usize, value: *const *const c_char);
    fmi2GetFMUstate(state: *mut *mut c_void);
    fmi2SetFMUstate(state: *mut c_void);
    fmi2FreeFMUstate(state: *mut *mut c_void);
    fmi2SerializedFMUstateSize(state: *mut c_void, size: *mut usize);
    fmi2SerializeFMUstate(state: *mut c_void, bytes: *mut c_char, size: usize);
    fmi2DeSerializeFMUstate(bytes: *const c_char, size: usize, state: *mut *mut c_void);
    fmi2GetDirectionalDerivative(a: *const c_uint, na: usize, b: *const c_uint, nb: usize, dv: *const f64, df: *mut f64);
    fmi2SetRealInputDerivatives(vr: *const c_uint, n: usize, order: *const c_int, value: *const f64);
    fmi2GetRealOutputDerivatives(vr: *const c_uint, n: usize, order: *const c_int, value: *mut f64);
    fmi2CancelStep();
    fmi2GetStatus(kind: c_int, value: *mut c_int);
    fmi2GetRealStatus(kind: c_int, value: *mut f64);
    fmi2GetIntegerStatus(kind: c_int, value: *mut c_int);
    fmi2GetBooleanStatus(kind: c_int, value: *mut c_int);
    fmi2GetStringStatus(kind: c_int, value: *mut *const c_char);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::variables::Variant;

    /// A component of the Sahu 2022 plant FMU with no logger.
    fn component() -> *mut c_void {
        let text = include_str!("../../../configs/sahu2022_force.toml");
        let guid = crate::xml::guid(text, Variant::Plant);
        let inst = Instance::new(text, Variant::Plant, &guid).unwrap();
        Box::into_raw(Box::new(Component {
            name: CString::new("t").unwrap(),
            logger: None,
            env: std::ptr::null_mut(),
            logging_on: false,
            inst,
        })) as *mut c_void
    }

    #[test]
    fn a_panic_inside_a_call_is_fmi2fatal_and_never_unwinds_into_the_host() {
        let c = component();
        assert_eq!(with(c, |_| panic!("boom")), FATAL);
        // the instance is still there and answers
        assert_eq!(with(c, |_| OK), OK);
        assert_eq!(with(std::ptr::null_mut(), |_| OK), ERROR);
        // SAFETY: `c` came from `component` and is freed once.
        unsafe { fmi2FreeInstance(c) };
    }

    #[test]
    fn a_wrong_guid_or_resource_location_instantiates_nothing() {
        let name = c"x";
        let err = |kind, uri| instantiate(name, kind, "{0}", uri).err().unwrap();
        assert!(err(1, "file:///nonexistent/resources")
            .contains("cannot read /nonexistent/resources/config.toml"));
        assert!(err(0, "file:///tmp").contains("co-simulation only"));
        assert!(err(1, "http://example.org/r").contains("no file URI"));
        let text = include_str!("../../../configs/sahu2022_force.toml");
        assert!(Instance::new(text, Variant::Plant, "{0}")
            .err()
            .unwrap()
            .contains("does not match"));
    }

    #[test]
    fn resource_uris_of_the_usual_forms_give_the_directory() {
        for (uri, dir) in [
            ("file:///a/b%20c/resources", "/a/b c/resources"),
            ("file:/a/resources", "/a/resources"),
            ("file://localhost/a/resources", "/a/resources"),
            ("file:///a/100%/r", "/a/100%/r"),
        ] {
            assert_eq!(
                resource_dir(uri).unwrap(),
                std::path::PathBuf::from(dir),
                "{uri}"
            );
        }
    }

    #[test]
    fn values_go_through_the_c_calls_and_bad_ones_are_refused() {
        let c = component();
        // SAFETY: FMI calls on a live component with arrays of the stated length.
        unsafe {
            assert_eq!(fmi2SetupExperiment(c, 0, 0.0, 0.0, 0, 0.0), OK);
            assert_eq!(fmi2EnterInitializationMode(c), OK);
            assert_eq!(fmi2ExitInitializationMode(c), OK);
            let u: c_uint = 9; // after the nine plant outputs
            assert_eq!(fmi2SetReal(c, &u, 1, &f64::NAN), ERROR);
            assert_eq!(fmi2SetReal(c, &u, 1, &2.0), OK);
            let mut got = 0.0;
            assert_eq!(fmi2GetReal(c, &u, 1, &mut got), OK);
            assert_eq!(got, 2.0);
            let mut b = 0;
            assert_eq!(fmi2GetBoolean(c, &u, 1, &mut b), ERROR);
            assert_eq!(fmi2DoStep(c, 0.0, 3.0e-4, 1), ERROR);
            assert_eq!(fmi2DoStep(c, 0.0, 4.0e-4, 1), OK);
            assert_eq!(fmi2DoStep(c, 4.0e-4, 2.0e-4, 1), OK);
            assert_eq!(fmi2GetString(c, &u, 0, std::ptr::null_mut()), ERROR);
            assert_eq!(fmi2Terminate(c), OK);
            fmi2FreeInstance(c);
        }
    }
}
