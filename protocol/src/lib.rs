//! The qhm host <-> rig MCU protocol.
//!
//! - [`messages`]: the one table of messages (commands, replies, events). Its
//!   schema (every struct and enum with its fields and variants, in order;
//!   not its comments) is hashed into [`SCHEMA_HASH`], which the host checks
//!   on connect, so a peer with any other message table is refused instead
//!   of misread.
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

// SCHEMA_HASH and SCHEMA_TEXT, written by build.rs from messages.rs
// (the canonical text is defined in schema.rs): a comment edit keeps the
// hash, any change to a name, field, type or order moves it, and the host
// refuses a peer whose hash differs.
include!(concat!(env!("OUT_DIR"), "/schema_hash.rs"));
