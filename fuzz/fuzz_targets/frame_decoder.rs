//! The streaming frame decoder over arbitrary bytes, as both ends use it:
//! it must never panic, whatever arrives, and every frame it accepts must
//! re-encode to a frame that decodes to the same message.
#![no_main]

use libfuzzer_sys::fuzz_target;
use protocol::{FrameDecoder, HostFrame, MAX_FRAME, McuFrame, encode_frame};

fn roundtrip<T: serde::Serialize + serde::de::DeserializeOwned + PartialEq + core::fmt::Debug>(
    msg: &T,
) {
    let mut buf = [0u8; MAX_FRAME];
    let n = encode_frame(msg, &mut buf).expect("a decoded message must re-encode");
    let mut dec = FrameDecoder::new();
    let mut back = None;
    dec.push_slice::<T>(&buf[..n], |r| back = Some(r));
    assert_eq!(back.as_ref().map(|r| r.as_ref().ok()), Some(Some(msg)));
}

fuzz_target!(|data: &[u8]| {
    let mut host = FrameDecoder::new();
    host.push_slice::<McuFrame>(data, |r| {
        if let Ok(m) = r {
            roundtrip(&m);
        }
    });
    let mut mcu = FrameDecoder::new();
    mcu.push_slice::<HostFrame>(data, |r| {
        if let Ok(m) = r {
            roundtrip(&m);
        }
    });
});
