//! Heartbeat consumer (CiA 301 §7.2.8.3.2.2): a monitored node must send its heartbeat
//! within the consumer time, else the node is lost. Time is injected ([`HeartbeatConsumer::process`]).

use crate::nmt::NmtState;

/// State of one monitored node.
#[derive(Debug, Clone)]
pub struct HeartbeatConsumer {
    /// Monitored node id.
    pub node: u8,
    timeout_ns: u64,
    since_ns: u64,
    last: Option<NmtState>,
    active: bool,
}

/// What the consumer saw.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HeartbeatEvent {
    /// No heartbeat within the consumer time (s since the last one, ns).
    Timeout {
        /// Time since the last heartbeat (ns).
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
            since_ns: 0,
            last: None,
            active: false,
        }
    }

    /// A heartbeat / boot-up of this node arrived with `state`.
    #[inline]
    pub fn on_heartbeat(&mut self, state: NmtState) -> Option<HeartbeatEvent> {
        self.since_ns = 0;
        self.active = true;
        let prev = self.last.replace(state);
        if state == NmtState::BootUp {
            return Some(HeartbeatEvent::BootUp);
        }
        (prev.is_some() && prev != Some(state)).then_some(HeartbeatEvent::StateChange(state))
    }

    /// Advance by `elapsed_ns`; reports a timeout once per loss.
    #[inline]
    pub fn process(&mut self, elapsed_ns: u64) -> Option<HeartbeatEvent> {
        if !self.active {
            return None;
        }
        self.since_ns = self.since_ns.saturating_add(elapsed_ns);
        if self.since_ns > self.timeout_ns {
            self.active = false;
            return Some(HeartbeatEvent::Timeout {
                silent_ns: self.since_ns,
            });
        }
        None
    }

    /// Start monitoring now even before the first heartbeat (after configuring 0x1017).
    pub fn arm(&mut self) {
        self.active = true;
        self.since_ns = 0;
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
        assert_eq!(h.on_heartbeat(NmtState::Operational), None);
        for _ in 0..60 {
            assert_eq!(h.process(1_000_000), None);
        }
        assert_eq!(
            h.process(1_000_000),
            Some(HeartbeatEvent::Timeout {
                silent_ns: 61_000_000
            })
        );
        assert_eq!(h.process(1_000_000), None);
    }

    #[test]
    fn heartbeats_reset_the_timer_and_report_changes() {
        let mut h = HeartbeatConsumer::new(0x20, 60_000_000);
        h.arm();
        for _ in 0..10 {
            assert_eq!(h.process(20_000_000), None);
            h.on_heartbeat(NmtState::Operational);
        }
        assert_eq!(
            h.on_heartbeat(NmtState::PreOperational),
            Some(HeartbeatEvent::StateChange(NmtState::PreOperational))
        );
        assert_eq!(
            h.on_heartbeat(NmtState::BootUp),
            Some(HeartbeatEvent::BootUp)
        );
    }
}
