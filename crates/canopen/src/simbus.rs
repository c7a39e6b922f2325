//! A bus in memory for the unit tests of the start-up and the backend on simulated time
//! ([`crate::clock::ManualClock`]): frames the test queues are received in order, every frame
//! sent is kept with the clock reading at which it was sent.

use crate::bus::{BusError, CanBus};
use crate::clock::{Clock, ManualClock};
use crate::frame::CanFrame;
use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// See the module docs. Clones share the queues (one for the RX, one for the TX thread).
#[derive(Clone)]
pub(crate) struct SimBus {
    clock: Arc<ManualClock>,
    /// Frames to receive, in order.
    pub(crate) rx: Arc<Mutex<VecDeque<CanFrame>>>,
    /// Frames sent, with the clock reading (ns).
    pub(crate) sent: Arc<Mutex<Vec<(u64, CanFrame)>>>,
    /// A wait with nothing to receive advances the clock by the whole wait (a single thread
    /// on simulated time); otherwise it takes at most 1 ms of real time and leaves the clock
    /// to the test (I/O threads paced by the test).
    advance_on_wait: bool,
}

impl SimBus {
    pub(crate) fn new(clock: Arc<ManualClock>, advance_on_wait: bool) -> SimBus {
        SimBus {
            clock,
            rx: Arc::default(),
            sent: Arc::default(),
            advance_on_wait,
        }
    }
}

impl CanBus for SimBus {
    fn send(&mut self, frame: &CanFrame) -> Result<(), BusError> {
        let now = self.clock.now_ns();
        self.sent.lock().unwrap().push((now, *frame));
        Ok(())
    }
    fn try_recv(&mut self) -> Result<Option<CanFrame>, BusError> {
        Ok(self.rx.lock().unwrap().pop_front())
    }
    fn recv_timeout(&mut self, timeout: Duration) -> Result<Option<CanFrame>, BusError> {
        if let Some(f) = self.rx.lock().unwrap().pop_front() {
            return Ok(Some(f));
        }
        if self.advance_on_wait {
            self.clock.advance(timeout);
        } else {
            std::thread::sleep(timeout.min(Duration::from_millis(1)));
        }
        Ok(None)
    }
    fn try_clone_bus(&self) -> Result<Box<dyn CanBus>, BusError> {
        Ok(Box::new(self.clone()))
    }
    fn describe(&self) -> String {
        "simulated bus".into()
    }
}
