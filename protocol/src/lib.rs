//! The qhm host <-> rig MCU protocol.
//!
//! - [`messages`]: the one table of messages (commands, replies, events). Its
//!   source text is hashed into [`SCHEMA_HASH`], which the host checks on
//!   connect, so a peer with any other message table is refused instead of
//!   misread.
//! - [`frame`]: postcard body, CRC-16, COBS with a 0x00 delimiter, bounded size;
//!   a streaming [`frame::FrameDecoder`] that never panics or allocates.
//! - [`seq`]: sequence-number rules: the MCU executes each command exactly once
//!   and answers retransmissions from a cache; events carry their own sequence
//!   and are re-sent until the host acknowledges them.
//!
//! `no_std`, no I/O: the firmware, the emulated MCU and the host all use it.
#![no_std]

#[cfg(any(feature = "std", test))]
extern crate std;

pub mod frame;
pub mod messages;
pub mod seq;

pub use frame::{FrameDecoder, FrameError, MAX_BODY, MAX_FRAME, decode_frame, encode_frame};
pub use messages::*;

/// Version of the wire protocol. Bumped on any incompatible change.
pub const PROTOCOL_VERSION: u16 = 1;

/// FNV-1a hash of the message table's source text: any change to a message
/// type changes it, and the host refuses a peer whose hash differs.
pub const SCHEMA_HASH: u32 = fnv1a(include_str!("messages.rs").as_bytes());

const fn fnv1a(bytes: &[u8]) -> u32 {
    let mut h: u32 = 0x811c_9dc5;
    let mut i = 0;
    while i < bytes.len() {
        h ^= bytes[i] as u32;
        h = h.wrapping_mul(0x0100_0193);
        i += 1;
    }
    h
}
