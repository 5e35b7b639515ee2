//! Framing: `COBS( postcard(message) ++ CRC-16(postcard bytes) ) ++ 0x00`.
//!
//! The 0x00 delimiter lets a receiver resynchronise after any garbage: it
//! drops bytes until the next delimiter. The CRC catches corruption COBS
//! cannot. Frames are bounded ([`MAX_FRAME`] bytes on the wire): a longer
//! run of bytes without a delimiter is discarded, never buffered.

use serde::{Serialize, de::DeserializeOwned};

/// CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF), little endian after the body.
pub const CRC: crc::Crc<u16> = crc::Crc::<u16>::new(&crc::CRC_16_IBM_3740);

/// Largest decoded frame body: postcard bytes plus the two CRC bytes.
pub const MAX_BODY: usize = 160;
/// Largest frame on the wire, delimiter included.
pub const MAX_FRAME: usize = cobs::max_encoding_length(MAX_BODY) + 1;

/// Why a frame could not be encoded or decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameError {
    /// The message does not fit in `MAX_BODY` (encoding) or the bytes between
    /// two delimiters exceeded `MAX_FRAME` (decoding).
    TooLong,
    /// Two delimiters with nothing between them.
    Empty,
    /// The bytes are not valid COBS.
    Cobs,
    /// Shorter than a CRC.
    TooShort,
    /// The CRC does not match: corrupted on the way.
    Crc,
    /// The CRC matched but the body is not a message of the expected type
    /// (or has trailing bytes): a peer with another schema.
    Deserialize,
}

impl core::fmt::Display for FrameError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            FrameError::TooLong => "frame longer than the protocol allows",
            FrameError::Empty => "empty frame",
            FrameError::Cobs => "invalid COBS encoding",
            FrameError::TooShort => "frame shorter than its CRC",
            FrameError::Crc => "CRC mismatch",
            FrameError::Deserialize => "frame body is not a valid message",
        })
    }
}

/// Encode `msg` as one complete frame (delimiter included) into `out`;
/// returns the number of bytes written.
pub fn encode_frame<T: Serialize>(msg: &T, out: &mut [u8]) -> Result<usize, FrameError> {
    let mut body = [0u8; MAX_BODY];
    let n = postcard::to_slice(msg, &mut body[..MAX_BODY - 2])
        .map_err(|_| FrameError::TooLong)?
        .len();
    let crc = CRC.checksum(&body[..n]);
    body[n..n + 2].copy_from_slice(&crc.to_le_bytes());
    let len = cobs::try_encode(&body[..n + 2], out).map_err(|_| FrameError::TooLong)?;
    if len >= out.len() {
        return Err(FrameError::TooLong);
    }
    out[len] = 0;
    Ok(len + 1)
}

/// Decode one frame's COBS bytes (without the delimiter) in place.
pub fn decode_frame<T: DeserializeOwned>(cobs_bytes: &mut [u8]) -> Result<T, FrameError> {
    if cobs_bytes.is_empty() {
        return Err(FrameError::Empty);
    }
    if cobs_bytes.len() > MAX_FRAME - 1 {
        return Err(FrameError::TooLong);
    }
    let n = cobs::decode_in_place(cobs_bytes).map_err(|_| FrameError::Cobs)?;
    if n < 2 {
        return Err(FrameError::TooShort);
    }
    let (body, crc) = cobs_bytes[..n].split_at(n - 2);
    if CRC.checksum(body) != u16::from_le_bytes([crc[0], crc[1]]) {
        return Err(FrameError::Crc);
    }
    match postcard::take_from_bytes::<T>(body) {
        Ok((msg, rest)) if rest.is_empty() => Ok(msg),
        _ => Err(FrameError::Deserialize),
    }
}

/// Streaming decoder: feed it bytes as they arrive; it yields a message (or
/// an error) at each delimiter. Fixed buffer, no allocation, no panics.
pub struct FrameDecoder {
    buf: [u8; MAX_FRAME],
    len: usize,
    /// Bytes since the last delimiter exceeded the buffer: drop until the next one.
    overflow: bool,
}

impl Default for FrameDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl FrameDecoder {
    pub const fn new() -> Self {
        Self {
            buf: [0; MAX_FRAME],
            len: 0,
            overflow: false,
        }
    }

    /// Forget any partial frame (after a link reset).
    pub fn reset(&mut self) {
        self.len = 0;
        self.overflow = false;
    }

    /// Feed one byte. Returns `None` until a delimiter completes a frame.
    /// Empty frames (delimiter runs) are skipped silently: senders may
    /// prefix frames with a delimiter to flush a receiver's partial garbage.
    pub fn push<T: DeserializeOwned>(&mut self, byte: u8) -> Option<Result<T, FrameError>> {
        if byte != 0 {
            if self.len < self.buf.len() {
                self.buf[self.len] = byte;
                self.len += 1;
            } else {
                self.overflow = true;
            }
            return None;
        }
        let (len, overflow) = (self.len, self.overflow);
        self.reset();
        if overflow {
            return Some(Err(FrameError::TooLong));
        }
        if len == 0 {
            return None;
        }
        Some(decode_frame(&mut self.buf[..len]))
    }

    /// Feed a slice, calling `on_frame` for every completed frame.
    pub fn push_slice<T: DeserializeOwned>(
        &mut self,
        bytes: &[u8],
        mut on_frame: impl FnMut(Result<T, FrameError>),
    ) {
        for &b in bytes {
            if let Some(r) = self.push(b) {
                on_frame(r);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::messages::*;
    use std::vec::Vec;

    fn roundtrip<T: Serialize + DeserializeOwned + PartialEq + core::fmt::Debug>(msg: T) {
        let mut out = [0u8; MAX_FRAME];
        let n = encode_frame(&msg, &mut out).unwrap();
        assert_eq!(out[n - 1], 0);
        assert!(out[..n - 1].iter().all(|&b| b != 0));
        let mut dec = FrameDecoder::new();
        let mut got = Vec::new();
        dec.push_slice::<T>(&out[..n], |r| got.push(r));
        assert_eq!(got, [Ok(msg)]);
    }

    fn biggest_identity() -> Identity {
        Identity {
            protocol_version: u16::MAX,
            schema_hash: u32::MAX,
            firmware_version: [255; 3],
            board: heapless::String::try_from("xxxxxxxxxxxxxxxxxxxxxxxx").unwrap(),
            boot_id: u32::MAX,
            limits: Limits {
                steps_per_rev: [u32::MAX; 2],
                max_speed_urad_s: [u32::MAX; 2],
                max_accel_urad_s2: [u32::MAX; 2],
                soft_min_urad: [i32::MIN; 2],
                soft_max_urad: [i32::MIN; 2],
                galvo_max_urad: i32::MIN,
                heartbeat_timeout_us: u32::MAX,
                lamps: 255,
                cameras: 255,
            },
        }
    }

    fn biggest_status() -> Status {
        let axis = AxisStatus {
            homed: true,
            moving: true,
            homing: true,
            position_steps: i32::MIN,
            target_steps: i32::MIN,
        };
        Status {
            uptime_us: u64::MAX,
            boot_id: u32::MAX,
            axes: [axis; 2],
            galvo_urad: i32::MIN,
            sweep_step: Some(u16::MAX),
            laser: LaserStatus {
                selected: LaserColour::Blue,
                power_permille: u16::MAX,
                armed: true,
                emitting: true,
            },
            lamps: 255,
            interlock_closed: true,
            estop_pressed: true,
            fault: Some(FaultCause::HomingFailed(Axis::LightArc)),
            last_eseq: u16::MAX,
            events_dropped: u16::MAX,
            last_seq: u16::MAX,
        }
    }

    #[test]
    fn largest_messages_fit() {
        roundtrip(McuFrame::Ack {
            seq: u16::MAX,
            result: Ok(Reply::Identity(biggest_identity())),
        });
        roundtrip(McuFrame::Ack {
            seq: u16::MAX,
            result: Ok(Reply::Status(biggest_status())),
        });
        roundtrip(McuFrame::Event {
            eseq: u16::MAX,
            at_us: u64::MAX,
            event: Event::TriggerFired {
                mask: 255,
                at_us: u64::MAX,
                pulse_us: u32::MAX,
            },
        });
        roundtrip(HostFrame {
            seq: u16::MAX,
            command: Command::GalvoSweep(Sweep {
                start_urad: i32::MIN,
                end_urad: i32::MIN,
                steps: u16::MAX,
                dwell_us: u32::MAX,
                trigger_mask: 255,
                pulse_us: u32::MAX,
            }),
        });
    }

    #[test]
    fn corruption_is_caught_and_decoder_resyncs() {
        let mut out = [0u8; MAX_FRAME];
        let msg = HostFrame {
            seq: 7,
            command: Command::Lamps { mask: 0b1010_1010 },
        };
        let n = encode_frame(&msg, &mut out).unwrap();
        let mut bad = out;
        bad[2] ^= 0x40;
        let mut dec = FrameDecoder::new();
        let mut got = Vec::new();
        dec.push_slice::<HostFrame>(&bad[..n], |r| got.push(r));
        dec.push_slice::<HostFrame>(&out[..n], |r| got.push(r));
        assert!(got[0].is_err());
        assert_eq!(got[1], Ok(msg));
    }

    #[test]
    fn overlong_garbage_is_dropped_not_buffered() {
        let mut dec = FrameDecoder::new();
        let mut got = Vec::new();
        for _ in 0..10 * MAX_FRAME {
            if let Some(r) = dec.push::<HostFrame>(0x55) {
                got.push(r);
            }
        }
        assert!(got.is_empty());
        assert_eq!(dec.push::<HostFrame>(0), Some(Err(FrameError::TooLong)));
    }

    proptest::proptest! {
        #[test]
        fn decoder_never_panics(bytes in proptest::collection::vec(proptest::num::u8::ANY, 0..2048)) {
            let mut dec = FrameDecoder::new();
            dec.push_slice::<McuFrame>(&bytes, |_| {});
            let mut dec = FrameDecoder::new();
            dec.push_slice::<HostFrame>(&bytes, |_| {});
        }
    }
}
