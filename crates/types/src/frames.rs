//! The hand-over of raw bus frames from a backend to the logger: [`CanFrameRecord`] (one
//! frame, fixed size) and [`FrameLog`] (bounded lock-free queues of frames and backend
//! events, crates/types/src/queue.rs). A CAN backend (crates/canopen/src/hal.rs) fills it and hands it out through
//! `Hal::frame_log`; the MCAP logger (crates/log/src/logger.rs, `Logger::attach_frames`)
//! drains it into `/can` and `/events`. Neither side compiles the other.

use crate::event::Event;
use crate::queue::LossyQueue;

/// One raw CAN frame seen by a CAN backend (fixed size, no heap).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CanFrameRecord {
    /// Time relative to the start of the control loop (ns); negative during start-up.
    pub t_ns: i64,
    /// CAN identifier.
    pub id: u32,
    /// 29-bit identifier.
    pub extended: bool,
    /// Data length (bytes).
    pub dlc: u8,
    /// Data (bytes beyond `dlc` are zero).
    pub data: [u8; 8],
    /// Sent by this process (true) or received (false).
    pub tx: bool,
}

/// Bounded lock-free queues of raw CAN frames and backend events from a backend (its I/O
/// threads and its cycle code) to whoever records them (the MCAP logger of `ehactl-log`
/// writes them to `/can` and `/events`): two [`LossyQueue`]s. Never blocks:
/// when full the frame or event is dropped and counted.
#[derive(Debug)]
pub struct FrameLog {
    frames: LossyQueue<CanFrameRecord>,
    events: LossyQueue<Event>,
}

impl FrameLog {
    /// Queue with room for `capacity` frames (at least 16) and 256 backend events.
    pub fn new(capacity: usize) -> FrameLog {
        FrameLog {
            frames: LossyQueue::new(capacity.max(16)),
            events: LossyQueue::new(256),
        }
    }

    /// Queue a backend event for `/events` (lock-free; counted as dropped if full).
    #[inline]
    pub fn push_event(&self, ev: Event) {
        self.events.push(ev);
    }

    /// Take the oldest backend event.
    pub fn pop_event(&self) -> Option<Event> {
        self.events.pop()
    }

    /// Backend events dropped so far.
    pub fn events_dropped(&self) -> u64 {
        self.events.dropped()
    }

    /// Queue a frame (lock-free, allocation-free); counts it as dropped if full.
    #[inline]
    pub fn push(&self, rec: CanFrameRecord) {
        self.frames.push(rec);
    }

    /// Take the oldest frame.
    pub fn pop(&self) -> Option<CanFrameRecord> {
        self.frames.pop()
    }

    /// Frames dropped so far.
    pub fn dropped(&self) -> u64 {
        self.frames.dropped()
    }

    /// Frames queued now.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Whether no frame is queued.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }
}
