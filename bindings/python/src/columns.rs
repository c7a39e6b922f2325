//! Every `CycleRecord` field as a named column. Sensor readings keep the `/control`
//! names (`force`, `position`, `p_a`, …); ground-truth plant states keep the `/plant` names
//! (`x`, `v`, `rod_force`, …) except where they would clash with a sensor or controller
//! column, which get a `plant_` prefix (`plant_p_a`, `plant_spool`, `plant_command`).

use ehactl_log::record::CycleRecord;

/// Column accessor.
pub(crate) type Getter = fn(&CycleRecord) -> f64;

/// (name, unit, accessor) of every float column, in a stable order.
pub(crate) const COLUMNS: &[(&str, &str, Getter)] = &[
    ("t", "s", |r| r.t),
    ("setpoint", "N or m", |r| r.setpoint),
    ("setpoint_rate", "N/s or m/s", |r| r.setpoint_rate),
    ("feedback", "N or m", |r| r.feedback),
    ("error", "N or m", |r| r.error),
    ("u", "V", |r| r.command),
    ("command_unsat", "V", |r| r.command_unsat),
    ("p_term", "V", |r| r.p_term),
    ("i_term", "V", |r| r.i_term),
    ("d_term", "V", |r| r.d_term),
    ("ff_term", "V", |r| r.ff_term),
    ("force", "N", |r| r.meas.force),
    ("position", "m", |r| r.meas.position),
    ("p_a", "Pa", |r| r.meas.p_a),
    ("p_b", "Pa", |r| r.meas.p_b),
    ("spool", "-", |r| r.meas.spool),
    ("plant_command", "V", |r| r.plant.command),
    ("plant_spool", "-", |r| r.plant.spool),
    ("spool_velocity", "1/s", |r| r.plant.spool_velocity),
    ("plant_p_a", "Pa", |r| r.plant.p_a),
    ("plant_p_b", "Pa", |r| r.plant.p_b),
    ("p_s", "Pa", |r| r.plant.p_s),
    ("x", "m", |r| r.plant.x),
    ("v", "m/s", |r| r.plant.v),
    ("x_load", "m", |r| r.plant.x_load),
    ("v_load", "m/s", |r| r.plant.v_load),
    ("q_a", "m³/s", |r| r.plant.q_a),
    ("q_b", "m³/s", |r| r.plant.q_b),
    ("friction", "N", |r| r.plant.friction),
    ("external", "N", |r| r.plant.external),
    ("rod_force", "N", |r| r.plant.rod_force),
];

/// Boolean column `stuck` (piston held by static friction) is handled separately.
pub(crate) const STUCK: &str = "stuck";

/// Column data of one run.
pub(crate) struct Columns {
    pub(crate) floats: Vec<(&'static str, Vec<f64>)>,
    pub(crate) cycle: Vec<u64>,
    pub(crate) stuck: Option<Vec<bool>>,
}

/// Resolve requested names (None = all) to column indices; unknown names are an error.
pub(crate) fn select(fields: Option<&[String]>) -> Result<(Vec<usize>, bool), String> {
    match fields {
        None => Ok(((0..COLUMNS.len()).collect(), true)),
        Some(names) => {
            let mut idx = Vec::new();
            let mut stuck = false;
            for n in names {
                if n == STUCK {
                    stuck = true;
                    continue;
                }
                if n == "cycle" {
                    continue;
                }
                match COLUMNS.iter().position(|c| c.0 == n) {
                    Some(i) => idx.push(i),
                    None => {
                        return Err(format!(
                            "unknown result field `{n}`; expected one of: cycle, {}, {STUCK}",
                            COLUMNS.iter().map(|c| c.0).collect::<Vec<_>>().join(", ")
                        ))
                    }
                }
            }
            Ok((idx, stuck))
        }
    }
}

/// Streams cycle records into the selected columns (the session's observer).
pub(crate) struct ColumnSink {
    idx: Vec<usize>,
    cols: Columns,
}

impl ColumnSink {
    /// Empty columns for `idx` (+ `stuck`), with room for `capacity` cycles.
    pub(crate) fn new(idx: &[usize], stuck: bool, capacity: usize) -> Self {
        Self {
            idx: idx.to_vec(),
            cols: Columns {
                floats: idx
                    .iter()
                    .map(|&i| (COLUMNS[i].0, Vec::with_capacity(capacity)))
                    .collect(),
                cycle: Vec::with_capacity(capacity),
                stuck: stuck.then(|| Vec::with_capacity(capacity)),
            },
        }
    }

    /// Append one record.
    pub(crate) fn push(&mut self, r: &CycleRecord) {
        for (&i, (_, v)) in self.idx.iter().zip(self.cols.floats.iter_mut()) {
            v.push((COLUMNS[i].2)(r));
        }
        self.cols.cycle.push(r.cycle);
        if let Some(s) = self.cols.stuck.as_mut() {
            s.push(r.plant.stuck);
        }
    }

    /// The filled columns.
    pub(crate) fn finish(self) -> Columns {
        self.cols
    }
}
