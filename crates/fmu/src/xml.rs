//! `modelDescription.xml` of the FMU (FMI 2.0, Modelica Association 2014, §2.2 and §4.3.1:
//! co-simulation), written from the variable table of [`crate::variables`].

use crate::variables::{Value, Var, Variant};
use crate::MODEL_IDENTIFIER;
use ehactl_config::RigConfig;
use std::fmt::Write;

/// Escape `s` for an XML attribute value.
fn esc(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            '\n' | '\r' | '\t' => o.push(' '),
            c => o.push(c),
        }
    }
    o
}

/// An xs:double: Rust's shortest round-trip form (`1000.0`, `5e-5`), which XML Schema reads
/// back to the same bits.
fn num(v: f64) -> String {
    format!("{v:?}")
}

/// The type element of one variable (`<Real …/>`, `<Integer …/>`, `<Boolean …/>`).
fn type_element(v: &Var) -> String {
    let mut a = String::new();
    let with_start = v.causality != "output";
    match v.start {
        Value::Real(s) => {
            if !v.unit.is_empty() {
                let _ = write!(a, " unit=\"{}\"", esc(&v.unit));
            }
            if with_start {
                let _ = write!(a, " start=\"{}\"", num(s));
            }
            if let Some(m) = v.min {
                let _ = write!(a, " min=\"{}\"", num(m));
            }
            if let Some(m) = v.max {
                let _ = write!(a, " max=\"{}\"", num(m));
            }
            format!("<Real{a}/>")
        }
        Value::Integer(s) => {
            if with_start {
                let _ = write!(a, " start=\"{s}\"");
            }
            // Integer bounds must be integers: the range's ends rounded inwards.
            if let Some(m) = v.min {
                let _ = write!(a, " min=\"{}\"", m.ceil().max(i32::MIN as f64) as i64);
            }
            if let Some(m) = v.max {
                let _ = write!(a, " max=\"{}\"", m.floor().min(i32::MAX as f64) as i64);
            }
            format!("<Integer{a}/>")
        }
        Value::Boolean(s) => {
            if with_start {
                let _ = write!(a, " start=\"{s}\"");
            }
            format!("<Boolean{a}/>")
        }
    }
}

/// A GUID for the FMU: FNV-1a (64 bit, twice with different offsets) over what the
/// model description is made of (the config text, the variant and ehactl's version), in the
/// 8-4-4-4-12 form. The shared library recomputes it at instantiate from the FMU's
/// resources and refuses an FMU whose description does not match.
pub fn guid(config_text: &str, variant: Variant) -> String {
    let fnv = |seed: u64| {
        let mut h = seed;
        for b in config_text
            .bytes()
            .chain(variant.as_str().bytes())
            .chain(env!("CARGO_PKG_VERSION").bytes())
        {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
        h
    };
    let (a, b) = (fnv(0xcbf2_9ce4_8422_2325), fnv(0x8422_2325_cbf2_9ce4));
    format!(
        "{{{:08x}-{:04x}-{:04x}-{:04x}-{:012x}}}",
        a >> 32,
        (a >> 16) & 0xffff,
        a & 0xffff,
        b >> 48,
        b & 0xffff_ffff_ffff
    )
}

/// The model description of `cfg` (read from `config_text`) as `variant`.
pub fn model_description(cfg: &RigConfig, config_text: &str, variant: Variant) -> String {
    let vars = crate::variables::table(cfg, variant);
    let mut units: Vec<&str> = vars
        .iter()
        .map(|v| v.unit.as_str())
        .filter(|u| !u.is_empty())
        .collect();
    units.sort_unstable();
    units.dedup();
    let name = if cfg.rig.name.is_empty() {
        "ehactl".to_string()
    } else {
        cfg.rig.name.clone()
    };
    let mut x = String::new();
    let _ = writeln!(x, "<?xml version=\"1.0\" encoding=\"UTF-8\"?>");
    let _ = writeln!(
        x,
        "<fmiModelDescription fmiVersion=\"2.0\" modelName=\"{}\" guid=\"{}\" description=\"{}\" generationTool=\"ehactl {}\" variableNamingConvention=\"flat\" numberOfEventIndicators=\"0\">",
        esc(&name),
        guid(config_text, variant),
        esc(&format!(
            "ehactl {} of the rig config: the plant crate's model with the substep integration of ehactl run",
            match variant {
                Variant::Plant => "plant",
                Variant::ClosedLoop => "closed loop (control law + supervisor + plant)",
            }
        )),
        env!("CARGO_PKG_VERSION"),
    );
    let _ = writeln!(
        x,
        "  <CoSimulation modelIdentifier=\"{MODEL_IDENTIFIER}\" needsExecutionTool=\"false\" canHandleVariableCommunicationStepSize=\"true\" canInterpolateInputs=\"false\" canRunAsynchronuously=\"false\" canBeInstantiatedOnlyOncePerProcess=\"false\" canNotUseMemoryManagementFunctions=\"true\" canGetAndSetFMUstate=\"false\" canSerializeFMUstate=\"false\" providesDirectionalDerivative=\"false\"/>"
    );
    let _ = writeln!(x, "  <UnitDefinitions>");
    for u in &units {
        let _ = writeln!(x, "    <Unit name=\"{}\"/>", esc(u));
    }
    let _ = writeln!(x, "  </UnitDefinitions>");
    let _ = writeln!(x, "  <LogCategories>");
    let _ = writeln!(
        x,
        "    <Category name=\"logStatusError\" description=\"refused calls and inputs\"/>"
    );
    let _ = writeln!(
        x,
        "    <Category name=\"logEvents\" description=\"supervisor trips\"/>"
    );
    let _ = writeln!(x, "  </LogCategories>");
    let tb = cfg.timebase();
    let _ = writeln!(
        x,
        "  <DefaultExperiment startTime=\"0.0\" stopTime=\"{}\" stepSize=\"{}\"/>",
        num(cfg.run.duration),
        num(tb.period())
    );
    let _ = writeln!(x, "  <ModelVariables>");
    for (i, v) in vars.iter().enumerate() {
        let initial = match v.causality {
            "parameter" => " initial=\"exact\"",
            _ => "",
        };
        let _ = writeln!(
            x,
            "    <!-- index {} -->\n    <ScalarVariable name=\"{}\" valueReference=\"{i}\" description=\"{}\" causality=\"{}\" variability=\"{}\"{initial}>\n      {}\n    </ScalarVariable>",
            i + 1,
            esc(&v.name),
            esc(&v.description),
            v.causality,
            v.variability,
            type_element(v)
        );
    }
    let _ = writeln!(x, "  </ModelVariables>");
    let _ = writeln!(x, "  <ModelStructure>");
    let outputs: Vec<usize> = (0..vars.len())
        .filter(|&i| vars[i].causality == "output")
        .collect();
    let _ = writeln!(x, "    <Outputs>");
    for i in &outputs {
        let _ = writeln!(x, "      <Unknown index=\"{}\"/>", i + 1);
    }
    let _ = writeln!(x, "    </Outputs>");
    let _ = writeln!(x, "    <InitialUnknowns>");
    for i in &outputs {
        let _ = writeln!(x, "      <Unknown index=\"{}\"/>", i + 1);
    }
    let _ = writeln!(x, "    </InitialUnknowns>");
    let _ = writeln!(x, "  </ModelStructure>");
    let _ = writeln!(x, "</fmiModelDescription>");
    x
}
