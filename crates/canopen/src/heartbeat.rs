//! Heartbeat consumer (CiA 301 §7.2.8.3.2.2): a monitored node must send its heartbeat
//! within the consumer time, else the node is lost. The consumer time runs from the
//! **reception** of the last heartbeat: each heartbeat is fed with its receive stamp and the
//! check compares the present time with it ([`HeartbeatConsumer::process`]), both in ns of
//! one monotonic clock, so that the moment a frame is taken in (e.g. once per control
//! cycle) and a control loop that lags the wall clock do not shift the window.

use crate::nmt::NmtState;

/// State of one monitored node.
#[derive(Debug, Clone)]
pub struct HeartbeatConsumer {
    /// Monitored node id.
    pub node: u8,
    timeout_ns: u64,
    /// Receive time of the last heartbeat (ns, monotonic clock of the caller).
    last_rx_ns: i64,
    last: Option<NmtState>,
    active: bool,
}

/// What the consumer saw.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HeartbeatEvent {
    /// No heartbeat within the consumer time.
    Timeout {
        /// Time since the reception of the last heartbeat (ns).
        silent_ns: u64,
    },
    /// The node reported a different NMT state than before.
    StateChange(NmtState),
    /// The node sent a boot-up: it was reset.
    BootUp,
}

impl HeartbeatConsumer {
    /// Consumer with timeout `timeout_ns` (ns); monitoring starts with the first heartbeat.
    pub fn new(node: u8, timeout_ns: u64) -> HeartbeatConsumer {
        HeartbeatConsumer {
            node,
            timeout_ns,
            last_rx_ns: 0,
            last: None,
            active: false,
        }
    }

    /// A heartbeat / boot-up of this node with `state` was received at `rx_ns` (ns).
    #[inline]
    pub fn on_heartbeat(&mut self, state: NmtState, rx_ns: i64) -> Option<HeartbeatEvent> {
        // frames are taken in in receive order; max() keeps the window from moving back
        self.last_rx_ns = if self.active {
            self.last_rx_ns.max(rx_ns)
        } else {
            rx_ns
        };
        self.active = true;
        let prev = self.last.replace(state);
        if state == NmtState::BootUp {
            return Some(HeartbeatEvent::BootUp);
        }
        (prev.is_some() && prev != Some(state)).then_some(HeartbeatEvent::StateChange(state))
    }

    /// Check at `now_ns` (ns, the clock of the receive stamps): reports a timeout once per
    /// loss, when more than the consumer time has passed since the last reception.
    #[inline]
    pub fn process(&mut self, now_ns: i64) -> Option<HeartbeatEvent> {
        if !self.active {
            return None;
        }
        let silent_ns = now_ns.saturating_sub(self.last_rx_ns).max(0) as u64;
        if silent_ns > self.timeout_ns {
            self.active = false;
            return Some(HeartbeatEvent::Timeout { silent_ns });
        }
        None
    }

    /// Start monitoring at `now_ns` even before the first heartbeat (after configuring
    /// 0x1017): the window runs as if a heartbeat had been received then.
    pub fn arm(&mut self, now_ns: i64) {
        self.active = true;
        self.last_rx_ns = now_ns;
    }

    /// Last reported state.
    pub fn state(&self) -> Option<NmtState> {
        self.last
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn times_out_after_the_consumer_time_once() {
        let mut h = HeartbeatConsumer::new(0x30, 60_000_000);
        assert_eq!(
            h.process(1_000_000_000),
            None,
            "not armed before the first heartbeat"
        );
        let t0 = 2_000_000_000;
        assert_eq!(h.on_heartbeat(NmtState::Operational, t0), None);
        for k in 0..=60 {
            assert_eq!(h.process(t0 + k * 1_000_000), None, "{k} ms");
        }
        assert_eq!(
            h.process(t0 + 61_000_000),
            Some(HeartbeatEvent::Timeout {
                silent_ns: 61_000_000
            })
        );
        assert_eq!(h.process(t0 + 62_000_000), None, "reported once");
    }

    #[test]
    fn the_window_runs_from_the_reception_not_from_the_intake() {
        // A heartbeat received at 10 ms but taken in (dispatched) only at 40 ms: the
        // consumer time runs from 10 ms, so a check at 71 ms (61 ms after the reception)
        // reports the loss; counting from the intake would report it at 101 ms.
        let mut h = HeartbeatConsumer::new(0x30, 60_000_000);
        h.arm(0);
        assert_eq!(h.process(40_000_000), None);
        h.on_heartbeat(NmtState::Operational, 10_000_000);
        assert_eq!(h.process(70_000_000), None);
        assert_eq!(
            h.process(71_000_000),
            Some(HeartbeatEvent::Timeout {
                silent_ns: 61_000_000
            })
        );
        // an older stamp taken in after a newer one does not move the window back
        let mut h = HeartbeatConsumer::new(0x30, 60_000_000);
        h.on_heartbeat(NmtState::Operational, 50_000_000);
        h.on_heartbeat(NmtState::Operational, 30_000_000);
        assert_eq!(h.process(100_000_000), None);
        // a stamp after the check time counts as silent for 0 ns
        assert_eq!(h.process(40_000_000), None);
    }

    #[test]
    fn heartbeats_reset_the_timer_and_report_changes() {
        let mut h = HeartbeatConsumer::new(0x20, 60_000_000);
        h.arm(0);
        for k in 1..=10 {
            assert_eq!(h.process(k * 50_000_000), None);
            h.on_heartbeat(NmtState::Operational, k * 50_000_000);
        }
        assert_eq!(
            h.on_heartbeat(NmtState::PreOperational, 550_000_000),
            Some(HeartbeatEvent::StateChange(NmtState::PreOperational))
        );
        assert_eq!(
            h.on_heartbeat(NmtState::BootUp, 560_000_000),
            Some(HeartbeatEvent::BootUp)
        );
    }
}
