//! Findings of the residual analysis of one replay ([`crate::analysis::analyse`]) and the
//! evidence rules several catalogue effects share (each effect's module in
//! [`crate::effects`] picks its rule: [`EffectFit::prior`](crate::effects::EffectFit::prior)).
//! Apart from `analysis.rs` so that the effect modules can read them without a file-level
//! circle (analysis.rs asks the effect modules for their prior).

use ehactl_plant::EffectId;

/// A narrow line in a residual spectrum.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct Peak {
    /// Channel (CSV column name).
    pub channel: &'static str,
    /// Frequency (Hz).
    pub frequency: f64,
    /// Amplitude of the equivalent sine (channel unit).
    pub amplitude: f64,
    /// Peak PSD over the median PSD of its neighbourhood (-).
    pub prominence: f64,
}

/// Findings of the residual analysis of one replay.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Analysis {
    /// Residual RMS over the record's RMS deviation, per channel (-).
    pub nrmse: Vec<f64>,
    /// Estimated sensor noise per channel (channel unit).
    pub noise: Vec<f64>,
    /// RMS residual within ±10 ms of velocity reversals over overall RMS (-).
    pub reversal_ratio: f64,
    /// RMS residual where |u| < 5 % of max |u| over overall RMS (-).
    pub small_command_ratio: f64,
    /// RMS residual where |u| > 70 % of max |u| over overall RMS (-).
    pub large_command_ratio: f64,
    /// |mean residual| / RMS residual, averaged over pressure channels (-): a level shift;
    /// None when the data has no pressure channel.
    pub bias_share: Option<f64>,
    /// Lag of the measured signal behind the model by cross-correlation (s), median over channels.
    pub lag: f64,
    /// Narrow residual lines (tones), strongest first.
    pub tones: Vec<Peak>,
    /// Frequency (Hz) where the residual-to-signal PSD ratio is largest below Nyquist/2
    /// (tones excluded): an unmodelled or shifted mode.
    pub mode_frequency: f64,
    /// That ratio (-).
    pub mode_ratio: f64,
    /// Prior score per effect (higher = more suspicious) and its evidence, catalogue order.
    #[serde(skip)]
    pub prior: Vec<(EffectId, f64, String)>,
}

#[cfg(test)]
impl Analysis {
    /// A residual analysis that names no evidence: NRMSE 0.1 on one channel, no noise, no
    /// tone, every ratio 1, a lag of 1 ms and a 30 Hz mode at 2× (the tests' fixture).
    pub(crate) fn neutral() -> Analysis {
        Analysis {
            nrmse: vec![0.1],
            noise: vec![0.0],
            reversal_ratio: 1.0,
            small_command_ratio: 1.0,
            large_command_ratio: 1.0,
            bias_share: None,
            lag: 1e-3,
            tones: vec![],
            mode_frequency: 30.0,
            mode_ratio: 2.0,
            prior: Vec::new(),
        }
    }
}

impl Analysis {
    /// Evidence of a flow or pressure limit at large commands (`valve_saturation`,
    /// `supply_pressure_drop`): the large-command residual ratio.
    pub(crate) fn large_command_prior(&self) -> (f64, String) {
        let large_command_ratio = self.large_command_ratio;
        (
            large_command_ratio,
            format!("residual RMS where |u| > 70 % of its maximum is {large_command_ratio:.2}× the overall RMS"),
        )
    }

    /// Evidence of a lag (`valve_dynamics`, `time_delay`): 1 + half the lag in samples of
    /// period `dt` (s).
    pub(crate) fn lag_prior(&self, dt: f64) -> (f64, String) {
        let lag = self.lag;
        (
            1.0 + (lag / dt).abs() / 2.0,
            format!(
                "measured outputs lag the model by {:.2} ms (cross-correlation, median over channels)",
                lag * 1e3
            ),
        )
    }

    /// Evidence of a shifted or unmodelled mode (`flexible_mount`, `line_dynamics`,
    /// `bulk_modulus_pressure`): 1 + the residual-to-signal spectrum ratio at its peak.
    pub(crate) fn mode_prior(&self) -> (f64, String) {
        let (mode_ratio, mode_frequency) = (self.mode_ratio, self.mode_frequency);
        (
            1.0 + mode_ratio,
            format!(
                "residual-to-signal spectrum ratio peaks near {mode_frequency:.1} Hz (a shifted or unmodelled mode)"
            ),
        )
    }
}
