//! A minimal native FMI 2.0 co-simulation host: loads an extracted ehactl FMU's shared
//! library with `dlopen` (FMI 2.0 §2.1: the C functions by their standard names), runs it and
//! prints the outputs as one JSON object. For the benchmark of one `fmi2DoStep` of one control
//! period against one `ehactl run` cycle (BENCHMARKS.md) and for the aarch64 build under QEMU
//! (scripts/qemu_run.sh), where no Python FMI host runs.
//!
//! Usage: `fmu_host DIR [--seconds S] [--reps N] [--platform P]` with DIR the FMU unzipped
//! (`python3 -m zipfile -e rig.fmu DIR`). A closed-loop FMU runs its config's setpoint
//! (`setpoint_from_config`), a plant FMU a valve command of 1 V. `--reps` repeats the run
//! (reset, re-initialise) and reports the median time per step; `--no-outputs` reads the
//! outputs only after the last step (the cost of `fmi2DoStep` alone).

use std::ffi::{c_char, c_int, c_uint, c_void, CStr, CString};
use std::time::Instant;

/// The logger as this host defines it: called with the message as the format and no further
/// arguments (what ehactl's FMU does), so the fixed-argument form reads what it is given.
type Logger = unsafe extern "C" fn(*mut c_void, *const c_char, c_int, *const c_char, *const c_char);

#[repr(C)]
struct Callbacks {
    logger: Option<Logger>,
    allocate: Option<unsafe extern "C" fn(usize, usize) -> *mut c_void>,
    free: Option<unsafe extern "C" fn(*mut c_void)>,
    step_finished: Option<unsafe extern "C" fn(*mut c_void, c_int)>,
    env: *mut c_void,
}

unsafe extern "C" fn logger(
    _: *mut c_void,
    name: *const c_char,
    status: c_int,
    cat: *const c_char,
    msg: *const c_char,
) {
    // SAFETY: the FMU passes NUL-terminated strings.
    let s = |p: *const c_char| unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned();
    eprintln!("[{}] status {status} {}: {}", s(name), s(cat), s(msg));
}

type Instantiate = unsafe extern "C" fn(
    *const c_char,
    c_int,
    *const c_char,
    *const c_char,
    *const Callbacks,
    c_int,
    c_int,
) -> *mut c_void;
type Setup = unsafe extern "C" fn(*mut c_void, c_int, f64, f64, c_int, f64) -> c_int;
type Unary = unsafe extern "C" fn(*mut c_void) -> c_int;
type DoStep = unsafe extern "C" fn(*mut c_void, f64, f64, c_int) -> c_int;
type GetReal = unsafe extern "C" fn(*mut c_void, *const c_uint, usize, *mut f64) -> c_int;
type SetReal = unsafe extern "C" fn(*mut c_void, *const c_uint, usize, *const f64) -> c_int;
type SetBool = unsafe extern "C" fn(*mut c_void, *const c_uint, usize, *const c_int) -> c_int;

/// The FMI functions of the loaded library.
struct Api {
    instantiate: Instantiate,
    setup: Setup,
    enter: Unary,
    exit: Unary,
    reset: Unary,
    terminate: Unary,
    free: unsafe extern "C" fn(*mut c_void),
    do_step: DoStep,
    get_real: GetReal,
    set_real: SetReal,
    set_bool: SetBool,
}

fn load(path: &str) -> Result<Api, String> {
    let p = CString::new(path).map_err(|e| e.to_string())?;
    // SAFETY: dlopen of a path; the handle stays open for the process.
    let h = unsafe { libc::dlopen(p.as_ptr(), libc::RTLD_NOW | libc::RTLD_LOCAL) };
    if h.is_null() {
        // SAFETY: dlerror returns a C string after a failed dlopen.
        return Err(unsafe { CStr::from_ptr(libc::dlerror()) }
            .to_string_lossy()
            .into_owned());
    }
    let sym = |name: &str| -> Result<*mut c_void, String> {
        let n = CString::new(name).map_err(|e| e.to_string())?;
        // SAFETY: dlsym on the open handle.
        let f = unsafe { libc::dlsym(h, n.as_ptr()) };
        (!f.is_null())
            .then_some(f)
            .ok_or(format!("{path}: no symbol {name}"))
    };
    // SAFETY: each symbol is the FMI 2.0 function of that name with the signature above.
    unsafe {
        Ok(Api {
            instantiate: std::mem::transmute::<*mut c_void, Instantiate>(sym("fmi2Instantiate")?),
            setup: std::mem::transmute::<*mut c_void, Setup>(sym("fmi2SetupExperiment")?),
            enter: std::mem::transmute::<*mut c_void, Unary>(sym("fmi2EnterInitializationMode")?),
            exit: std::mem::transmute::<*mut c_void, Unary>(sym("fmi2ExitInitializationMode")?),
            reset: std::mem::transmute::<*mut c_void, Unary>(sym("fmi2Reset")?),
            terminate: std::mem::transmute::<*mut c_void, Unary>(sym("fmi2Terminate")?),
            free: std::mem::transmute::<*mut c_void, unsafe extern "C" fn(*mut c_void)>(sym(
                "fmi2FreeInstance",
            )?),
            do_step: std::mem::transmute::<*mut c_void, DoStep>(sym("fmi2DoStep")?),
            get_real: std::mem::transmute::<*mut c_void, GetReal>(sym("fmi2GetReal")?),
            set_real: std::mem::transmute::<*mut c_void, SetReal>(sym("fmi2SetReal")?),
            set_bool: std::mem::transmute::<*mut c_void, SetBool>(sym("fmi2SetBoolean")?),
        })
    }
}

/// The value of attribute `attr` of the first element carrying `key` (e.g. `name="x"`).
fn attr(xml: &str, key: &str, attr: &str) -> Option<String> {
    let at = xml.find(key)?;
    let start = xml[..at].rfind('<')?;
    let end = at + xml[at..].find('>')?;
    let el = &xml[start..end];
    let i = el.find(&format!(" {attr}=\""))? + attr.len() + 3;
    Some(el[i..i + el[i..].find('"')?].to_string())
}

fn vr(xml: &str, name: &str) -> Option<c_uint> {
    attr(xml, &format!("name=\"{name}\""), "valueReference")?
        .parse()
        .ok()
}

fn check(what: &str, s: c_int) -> Result<(), String> {
    if s <= 1 {
        Ok(())
    } else {
        Err(format!("{what} returned status {s}"))
    }
}

fn main() {
    if let Err(e) = run() {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}

/// The command line: `DIR [--seconds S] [--reps N] [--platform P] [--no-outputs]`.
struct HostArgs {
    /// The unpacked FMU.
    dir: String,
    /// Simulated time per repetition (s).
    seconds: f64,
    /// Read the outputs after every step (not only the last).
    every_step: bool,
    /// Repetitions (the median is printed).
    reps: usize,
    /// The FMU's platform folder under `binaries/`.
    platform: String,
}

fn parse_args() -> Result<HostArgs, String> {
    let args: Vec<String> = std::env::args().collect();
    let dir = args
        .get(1)
        .cloned()
        .ok_or("usage: fmu_host DIR [--seconds S] [--reps N] [--platform P]")?;
    let opt = |flag: &str| {
        args.iter()
            .position(|a| a == flag)
            .and_then(|i| args.get(i + 1))
    };
    let seconds: f64 = opt("--seconds")
        .map_or(Ok(1.0), |s| s.parse())
        .map_err(|e| format!("--seconds: {e}"))?;
    let every_step = !args.iter().any(|a| a == "--no-outputs");
    let reps: usize = opt("--reps")
        .map_or(Ok(1), |s| s.parse())
        .map_err(|e| format!("--reps: {e}"))?;
    let platform = opt("--platform").cloned().unwrap_or_else(|| {
        if cfg!(target_arch = "aarch64") {
            "aarch64-linux"
        } else {
            "linux64"
        }
        .to_string()
    });
    Ok(HostArgs {
        dir,
        seconds,
        every_step,
        reps,
        platform,
    })
}

fn run() -> Result<(), String> {
    let HostArgs {
        dir,
        seconds,
        every_step,
        reps,
        platform,
    } = parse_args()?;
    let xml = std::fs::read_to_string(format!("{dir}/modelDescription.xml"))
        .map_err(|e| format!("{dir}: {e}"))?;
    let guid = attr(&xml, "fmiModelDescription ", "guid").ok_or("no guid")?;
    let dt: f64 = attr(&xml, "<DefaultExperiment", "stepSize")
        .and_then(|s| s.parse().ok())
        .ok_or("no stepSize")?;
    let api = load(&format!("{dir}/binaries/{platform}/ehactl_fmu.so"))?;
    let abs = std::fs::canonicalize(dir).map_err(|e| e.to_string())?;
    let cb = Callbacks {
        logger: Some(logger),
        allocate: None,
        free: None,
        step_finished: None,
        env: std::ptr::null_mut(),
    };
    let (name, g, res) = (
        CString::new("host").unwrap_or_default(),
        CString::new(guid).unwrap_or_default(),
        CString::new(format!("file://{}/resources", abs.display())).unwrap_or_default(),
    );
    // SAFETY: the FMI 2.0 calling sequence on one instance, arguments as the standard defines.
    unsafe {
        let c = (api.instantiate)(name.as_ptr(), 1, g.as_ptr(), res.as_ptr(), &cb, 0, 0);
        if c.is_null() {
            return Err("fmi2Instantiate failed".into());
        }
        let outs: Vec<(&str, c_uint)> = ["x", "v", "p_a", "p_b", "force_measured", "force_load"]
            .iter()
            .filter_map(|n| vr(&xml, n).map(|r| (*n, r)))
            .collect();
        let refs: Vec<c_uint> = outs.iter().map(|o| o.1).collect();
        let mut y = vec![0.0; refs.len()];
        let steps = (seconds / dt).round() as usize;
        let mut per_step = Vec::new();
        for rep in 0..reps {
            if rep > 0 {
                check("fmi2Reset", (api.reset)(c))?;
            }
            check("fmi2SetupExperiment", (api.setup)(c, 0, 0.0, 0.0, 0, 0.0))?;
            check("fmi2EnterInitializationMode", (api.enter)(c))?;
            if let Some(r) = vr(&xml, "setpoint_from_config") {
                check("fmi2SetBoolean", (api.set_bool)(c, &r, 1, &1))?;
            }
            check("fmi2ExitInitializationMode", (api.exit)(c))?;
            let u = vr(&xml, "u");
            let t0 = Instant::now();
            for k in 0..steps {
                if let Some(r) = u {
                    check("fmi2SetReal", (api.set_real)(c, &r, 1, &1.0))?;
                }
                check("fmi2DoStep", (api.do_step)(c, k as f64 * dt, dt, 1))?;
                if every_step || k + 1 == steps {
                    check(
                        "fmi2GetReal",
                        (api.get_real)(c, refs.as_ptr(), refs.len(), y.as_mut_ptr()),
                    )?;
                }
            }
            per_step.push(t0.elapsed().as_secs_f64() / steps.max(1) as f64);
        }
        check("fmi2Terminate", (api.terminate)(c))?;
        (api.free)(c);
        per_step.sort_by(f64::total_cmp);
        let median = per_step[per_step.len() / 2];
        let fields: Vec<String> = outs
            .iter()
            .zip(&y)
            .map(|((n, _), v)| format!("\"{n}\": {v:?}"))
            .collect();
        println!(
            "{{\"platform\": \"{platform}\", \"steps\": {steps}, \"step_s\": {dt:?}, \"reps\": {reps}, \"median_s_per_step\": {median:?}, {}}}",
            fields.join(", ")
        );
    }
    Ok(())
}
