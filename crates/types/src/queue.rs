//! [`LossyQueue`]: the one bounded, lock-free, never-blocking hand-over between threads that
//! may lose what does not fit. Whoever pushes never waits and never allocates; an item that
//! finds the queue full is dropped and counted, so that a slow consumer (the MCAP writer, a
//! live viewer) can never slow the one that produces (the control cycle, a CAN backend's I/O
//! threads, the control socket).
//!
//! Its users: the raw bus frames and backend events a CAN backend hands to the logger
//! ([`crate::frames::FrameLog`]), the log's copy for a live viewer and the notes of the
//! control socket (`ehactl_log::logger::{LogTap, NoteLog}`, crates/log/src/logger.rs).
//! The logger's own cycle-record queue is not one of them: under its `Block` overflow policy
//! the producer waits for room rather than lose a record.
//!
//! The storage is `crossbeam_queue::ArrayQueue` (a fixed ring allocated once, in
//! [`LossyQueue::new`]; Vyukov's bounded MPMC queue, D. Vyukov, "Bounded MPMC queue",
//! 1024cores.net, 2010).

use crossbeam_queue::ArrayQueue;
use std::sync::atomic::{AtomicU64, Ordering};

/// A bounded multi-producer multi-consumer queue of `T` that drops (and counts) what does
/// not fit. Lock-free; no allocation after [`LossyQueue::new`].
#[derive(Debug)]
pub struct LossyQueue<T> {
    queue: ArrayQueue<T>,
    dropped: AtomicU64,
}

impl<T> LossyQueue<T> {
    /// A queue with room for `capacity` items (at least one: a capacity of 0 holds one).
    pub fn new(capacity: usize) -> LossyQueue<T> {
        LossyQueue {
            queue: ArrayQueue::new(capacity.max(1)),
            dropped: AtomicU64::new(0),
        }
    }

    /// Queue `item`; if the queue is full, drop it, count it and return false. Never blocks.
    #[inline]
    pub fn push(&self, item: T) -> bool {
        if self.queue.push(item).is_err() {
            self.dropped.fetch_add(1, Ordering::Relaxed);
            return false;
        }
        true
    }

    /// Take the oldest item.
    #[inline]
    pub fn pop(&self) -> Option<T> {
        self.queue.pop()
    }

    /// Items dropped so far because the queue was full.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Items queued now.
    pub fn len(&self) -> usize {
        self.queue.len()
    }

    /// Whether no item is queued.
    pub fn is_empty(&self) -> bool {
        self.queue.is_empty()
    }

    /// How many items the queue holds when full.
    pub fn capacity(&self) -> usize {
        self.queue.capacity()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    #[test]
    fn full_queue_drops_and_counts_in_order() {
        let q = LossyQueue::new(3);
        assert_eq!(q.capacity(), 3);
        for i in 0..5 {
            assert_eq!(q.push(i), i < 3, "push {i}");
        }
        assert_eq!((q.len(), q.dropped()), (3, 2));
        assert_eq!(
            std::iter::from_fn(|| q.pop()).collect::<Vec<_>>(),
            [0, 1, 2]
        );
        assert!(q.is_empty());
        assert!(q.push(7));
        assert_eq!((q.pop(), q.dropped()), (Some(7), 2));
    }

    #[test]
    fn zero_capacity_holds_one() {
        let q = LossyQueue::new(0);
        assert!(q.push('a'));
        assert!(!q.push('b'));
        assert_eq!((q.capacity(), q.dropped()), (1, 1));
    }

    #[test]
    fn every_push_of_many_threads_is_either_kept_or_counted() {
        let q = Arc::new(LossyQueue::new(64));
        let per_thread = 10_000u64;
        let producers: Vec<_> = (0..4)
            .map(|k| {
                let q = Arc::clone(&q);
                std::thread::spawn(move || {
                    for i in 0..per_thread {
                        q.push(k * per_thread + i);
                    }
                })
            })
            .collect();
        let mut seen = 0u64;
        while producers.iter().any(|p| !p.is_finished()) {
            while q.pop().is_some() {
                seen += 1;
            }
        }
        for p in producers {
            p.join().unwrap();
        }
        while q.pop().is_some() {
            seen += 1;
        }
        assert_eq!(seen + q.dropped(), 4 * per_thread);
    }
}
