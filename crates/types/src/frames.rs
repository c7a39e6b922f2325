//! The hand-over of raw bus frames from a backend to the logger: [`CanFrameRecord`] (one
//! frame, fixed size) and [`FrameLog`] (bounded lock-free queues of frames and backend
//! events). A CAN backend (crates/canopen/src/hal.rs) fills it and hands it out through
//! `Hal::frame_log`; the MCAP logger (crates/log/src/logger.rs, `Logger::attach_frames`)
//! drains it into `/can` and `/events`. Neither side compiles the other.

use crate::event::Event;
use crossbeam_queue::ArrayQueue;
use std::sync::atomic::{AtomicU64, Ordering};

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
/// writes them to `/can` and `/events`). Never blocks:
/// when full the frame or event is dropped and counted.
#[derive(Debug)]
pub struct FrameLog {
    queue: ArrayQueue<CanFrameRecord>,
    events: ArrayQueue<Event>,
    dropped: AtomicU64,
    events_dropped: AtomicU64,
}

impl FrameLog {
    /// Queue with room for `capacity` frames.
    pub fn new(capacity: usize) -> FrameLog {
        FrameLog {
            queue: ArrayQueue::new(capacity.max(16)),
            events: ArrayQueue::new(256),
            dropped: AtomicU64::new(0),
            events_dropped: AtomicU64::new(0),
        }
    }

    /// Queue a backend event for `/events` (lock-free; counted as dropped if full).
    #[inline]
    pub fn push_event(&self, ev: Event) {
        if self.events.push(ev).is_err() {
            self.events_dropped.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Take the oldest backend event.
    pub fn pop_event(&self) -> Option<Event> {
        self.events.pop()
    }

    /// Backend events dropped so far.
    pub fn events_dropped(&self) -> u64 {
        self.events_dropped.load(Ordering::Relaxed)
    }

    /// Queue a frame (lock-free, allocation-free); counts it as dropped if full.
    #[inline]
    pub fn push(&self, rec: CanFrameRecord) {
        if self.queue.push(rec).is_err() {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Take the oldest frame.
    pub fn pop(&self) -> Option<CanFrameRecord> {
        self.queue.pop()
    }

    /// Frames dropped so far.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Frames queued now.
    pub fn len(&self) -> usize {
        self.queue.len()
    }

    /// Whether no frame is queued.
    pub fn is_empty(&self) -> bool {
        self.queue.is_empty()
    }
}
