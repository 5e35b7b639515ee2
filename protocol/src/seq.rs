//! Sequence rules shared by both ends.
//!
//! Commands: the host has one command in flight at a time (stop and wait) and
//! numbers them; the MCU executes a command whose sequence is `last + 1`,
//! answers a command whose sequence equals `last` from its cached reply
//! (a retransmission: never executed twice) and refuses anything else.
//! `Identify` is accepted with any sequence and restarts the count.
//!
//! Events: the MCU numbers them, keeps unacknowledged ones in a bounded queue
//! and re-sends them until the host acknowledges; the host drops duplicates.

use crate::messages::{Command, CommandError, Event, HostFrame};

/// Is `a` after `b` in wrapping u16 sequence space?
pub const fn seq_after(a: u16, b: u16) -> bool {
    let d = a.wrapping_sub(b);
    d != 0 && d < 0x8000
}

/// What the MCU should do with an incoming command frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Admission {
    /// New command: execute it, then cache and send the reply.
    Execute,
    /// Same sequence as the last executed command: resend the cached reply.
    Retransmission,
    /// Refuse with this error (not executed, not cached).
    Refuse(CommandError),
}

/// MCU side: which command sequence numbers to execute.
#[derive(Debug, Clone, Default)]
pub struct CommandSequencer {
    /// Sequence of the last executed command, once identified since boot.
    last: Option<u16>,
}

impl CommandSequencer {
    pub const fn new() -> Self {
        Self { last: None }
    }

    /// Decide, and if `Execute`, record the sequence as executed.
    pub fn admit(&mut self, frame: &HostFrame) -> Admission {
        match (self.last, &frame.command) {
            (Some(last), _) if frame.seq == last => Admission::Retransmission,
            (_, Command::Identify) => {
                self.last = Some(frame.seq);
                Admission::Execute
            }
            (None, _) => Admission::Refuse(CommandError::NotIdentified),
            (Some(last), _) if frame.seq == last.wrapping_add(1) => {
                self.last = Some(frame.seq);
                Admission::Execute
            }
            (Some(last), _) => Admission::Refuse(CommandError::OutOfSequence {
                expected: last.wrapping_add(1),
            }),
        }
    }

    pub fn last(&self) -> Option<u16> {
        self.last
    }
}

/// MCU side: events awaiting acknowledgement, bounded; overflow is counted.
#[derive(Debug, Clone)]
pub struct EventQueue<const N: usize> {
    pending: heapless::Deque<(u16, u64, Event), N>,
    next_eseq: u16,
    dropped: u16,
}

impl<const N: usize> Default for EventQueue<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> EventQueue<N> {
    pub const fn new() -> Self {
        Self {
            pending: heapless::Deque::new(),
            next_eseq: 1,
            dropped: 0,
        }
    }

    /// Queue an event raised at `at_us`; returns its sequence number. When
    /// full, the oldest unacknowledged event is dropped and counted.
    pub fn push(&mut self, at_us: u64, event: Event) -> u16 {
        let eseq = self.next_eseq;
        self.next_eseq = self.next_eseq.wrapping_add(1);
        if self.pending.is_full() {
            self.pending.pop_front();
            self.dropped = self.dropped.saturating_add(1);
        }
        // cannot fail: made room above
        let _ = self.pending.push_back((eseq, at_us, event));
        eseq
    }

    /// The host has seen every event up to and including `upto`.
    pub fn ack(&mut self, upto: u16) {
        while let Some(&(eseq, _, _)) = self.pending.front() {
            if eseq == upto || seq_after(upto, eseq) {
                self.pending.pop_front();
            } else {
                break;
            }
        }
    }

    /// Unacknowledged events, oldest first.
    pub fn pending(&self) -> impl Iterator<Item = &(u16, u64, Event)> {
        self.pending.iter()
    }

    /// Sequence of the newest event raised (0 before any).
    pub fn last_eseq(&self) -> u16 {
        self.next_eseq.wrapping_sub(1)
    }

    pub fn dropped(&self) -> u16 {
        self.dropped
    }

    pub fn clear(&mut self) {
        self.pending.clear();
    }
}

/// Host side: drops duplicate events, tracks what to acknowledge.
#[derive(Debug, Clone, Default)]
pub struct EventReceiver {
    /// Newest event sequence delivered to the application.
    last: u16,
}

impl EventReceiver {
    pub const fn new() -> Self {
        Self { last: 0 }
    }

    /// Start over after a handshake (the MCU's event numbering restarts at boot).
    pub fn reset(&mut self, last: u16) {
        self.last = last;
    }

    /// True if the event is new and should be delivered. Events arrive in
    /// order from the MCU's queue; a later one than expected means some were
    /// dropped on the MCU (its status counts them).
    pub fn accept(&mut self, eseq: u16) -> bool {
        if seq_after(eseq, self.last) {
            self.last = eseq;
            true
        } else {
            false
        }
    }

    /// What to acknowledge: everything up to here has been delivered.
    pub fn ack_upto(&self) -> u16 {
        self.last
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn f(seq: u16, command: Command) -> HostFrame {
        HostFrame { seq, command }
    }

    #[test]
    fn exactly_once() {
        let mut s = CommandSequencer::new();
        assert_eq!(
            s.admit(&f(5, Command::Status)),
            Admission::Refuse(CommandError::NotIdentified)
        );
        assert_eq!(s.admit(&f(5, Command::Identify)), Admission::Execute);
        assert_eq!(s.admit(&f(5, Command::Identify)), Admission::Retransmission);
        assert_eq!(s.admit(&f(6, Command::Abort)), Admission::Execute);
        assert_eq!(s.admit(&f(6, Command::Abort)), Admission::Retransmission);
        assert_eq!(
            s.admit(&f(8, Command::Abort)),
            Admission::Refuse(CommandError::OutOfSequence { expected: 7 })
        );
        assert_eq!(s.admit(&f(7, Command::Abort)), Admission::Execute);
    }

    #[test]
    fn sequence_wraps() {
        let mut s = CommandSequencer::new();
        assert_eq!(s.admit(&f(u16::MAX, Command::Identify)), Admission::Execute);
        assert_eq!(s.admit(&f(0, Command::Status)), Admission::Execute);
        assert!(seq_after(0, u16::MAX));
        assert!(!seq_after(u16::MAX, 0));
    }

    #[test]
    fn event_queue_acks_and_counts_drops() {
        let mut q = EventQueue::<4>::new();
        for i in 0..6 {
            q.push(i, Event::Interlock { closed: i % 2 == 0 });
        }
        assert_eq!(q.dropped(), 2);
        assert_eq!(
            q.pending().map(|e| e.0).collect::<std::vec::Vec<_>>(),
            [3, 4, 5, 6]
        );
        q.ack(4);
        assert_eq!(
            q.pending().map(|e| e.0).collect::<std::vec::Vec<_>>(),
            [5, 6]
        );
        let mut r = EventReceiver::new();
        assert!(r.accept(5));
        assert!(!r.accept(5));
        assert!(r.accept(6));
        assert_eq!(r.ack_upto(), 6);
    }
}
