//! The outgoing byte queue: whole frames in, bytes out.
//!
//! Frames are queued complete or not at all; when the queue is full a frame
//! is dropped and counted (the host retransmits its command, and events are
//! re-sent until acknowledged). `take` hands out whole frames where they fit,
//! so a caller with a large enough buffer never sees half a frame.

/// Queue capacity in bytes: a dozen largest frames.
pub const TX_CAPACITY: usize = 2048;

pub struct TxQueue {
    buf: heapless::Deque<u8, TX_CAPACITY>,
    pushed: u64,
    taken: u64,
    overflows: u32,
}

impl Default for TxQueue {
    fn default() -> Self {
        Self::new()
    }
}

impl TxQueue {
    pub const fn new() -> Self {
        TxQueue {
            buf: heapless::Deque::new(),
            pushed: 0,
            taken: 0,
            overflows: 0,
        }
    }

    /// Queue a complete frame, or drop it (counted) if it does not fit.
    pub fn push_frame(&mut self, frame: &[u8]) {
        if self.buf.capacity() - self.buf.len() < frame.len() {
            self.overflows = self.overflows.wrapping_add(1);
            return;
        }
        for &b in frame {
            // cannot fail: room checked above
            let _ = self.buf.push_back(b);
        }
        self.pushed += frame.len() as u64;
    }

    /// Move bytes into `out`: every complete frame that fits; if not even the
    /// first one fits, as many of its bytes as `out` holds.
    pub fn take(&mut self, out: &mut [u8]) -> usize {
        let avail = out.len().min(self.buf.len());
        // end of the last complete frame within `avail`, else a partial frame
        let mut end = 0;
        for (i, &b) in self.buf.iter().take(avail).enumerate() {
            if b == 0 {
                end = i + 1;
            }
        }
        if end == 0 {
            end = avail;
        }
        for slot in out.iter_mut().take(end) {
            // cannot fail: end <= len
            *slot = self.buf.pop_front().unwrap_or(0);
        }
        self.taken += end as u64;
        end
    }

    /// Bytes queued since boot.
    pub fn pushed(&self) -> u64 {
        self.pushed
    }

    /// Bytes taken since boot.
    pub fn taken(&self) -> u64 {
        self.taken
    }

    pub fn overflows(&self) -> u32 {
        self.overflows
    }

    /// Bytes waiting.
    pub fn len(&self) -> usize {
        self.buf.len()
    }

    pub fn is_empty(&self) -> bool {
        self.buf.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn whole_frames_where_they_fit() {
        let mut q = TxQueue::new();
        q.push_frame(&[1, 2, 3, 0]);
        q.push_frame(&[4, 5, 0]);
        let mut out = [0u8; 6];
        assert_eq!(q.take(&mut out), 4);
        assert_eq!(&out[..4], &[1, 2, 3, 0]);
        // a buffer smaller than the frame still makes progress
        let mut small = [0u8; 2];
        assert_eq!(q.take(&mut small), 2);
        assert_eq!(small, [4, 5]);
        assert_eq!(q.take(&mut small), 1);
        assert_eq!(q.taken(), 7);
        assert!(q.is_empty());
    }

    #[test]
    fn overflow_drops_whole_frames() {
        let mut q = TxQueue::new();
        let frame = [7u8; 100];
        for _ in 0..25 {
            q.push_frame(&frame);
        }
        assert_eq!(q.pushed(), 2000);
        assert_eq!(q.overflows(), 5);
    }
}
