//! Byte streams the link runs over: a serial device (raw 8N1, a real UART or
//! a pseudo-terminal from the emulator) or any in-process async stream.
//!
//! `serialport` opens and configures the device; the file descriptor is then
//! switched to non-blocking and driven by tokio's reactor (`AsyncFd`), so the
//! reader and writer never occupy a blocking thread.

use std::fs::File;
use std::future::Future;
use std::io::{self, Read, Write};
use std::mem::ManuallyDrop;
use std::os::fd::{AsRawFd, BorrowedFd, FromRawFd, RawFd};
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll, ready};
use std::time::Duration;

use nix::fcntl::{FcntlArg, OFlag, fcntl};
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

use crate::LinkError;

/// Anything the link can run over.
pub trait ByteStream: AsyncRead + AsyncWrite + Send + Unpin + 'static {}
impl<T: AsyncRead + AsyncWrite + Send + Unpin + 'static> ByteStream for T {}

pub type BoxStream = Box<dyn ByteStream>;

/// Opens (or reopens) the byte stream; kept by the link for `reconnect()`.
pub type Connector = Arc<
    dyn Fn() -> Pin<Box<dyn Future<Output = Result<BoxStream, LinkError>> + Send>> + Send + Sync,
>;

/// Default baud rate (the Nucleo's ST-LINK virtual COM port).
pub const DEFAULT_BAUD: u32 = 115_200;

/// Baud rates a UART can run at: from the slowest rate termios names (50)
/// to the fastest USB-serial adapters (FT232H, 12 Mbaud; the STM32F446's
/// USART tops out near 11 Mbaud).
pub const BAUD_RANGE: std::ops::RangeInclusive<u32> = 50..=12_000_000;

/// `baud` if a UART can run at it, else the sentence that says why not.
pub fn check_baud(baud: u32) -> Result<u32, String> {
    if BAUD_RANGE.contains(&baud) {
        Ok(baud)
    } else {
        Err(format!(
            "baud rate {baud} is not one a UART can run at: give {} to {} bits/s",
            BAUD_RANGE.start(),
            BAUD_RANGE.end()
        ))
    }
}

/// A serial device as a tokio stream.
pub struct SerialStream {
    fd: AsyncFd<serialport::TTYPort>,
}

impl SerialStream {
    /// Open `path` raw 8N1 at `baud`, no flow control, exclusive, with
    /// whatever the device received while nobody listened discarded. Must be
    /// called inside a tokio runtime (the fd joins its reactor).
    pub fn open(path: &str, baud: u32) -> Result<Self, LinkError> {
        let err = |reason: String| LinkError::Open {
            path: path.to_string(),
            reason,
        };
        check_baud(baud).map_err(err)?;
        let port = serialport::new(path, baud)
            .data_bits(serialport::DataBits::Eight)
            .parity(serialport::Parity::None)
            .stop_bits(serialport::StopBits::One)
            .flow_control(serialport::FlowControl::None)
            .timeout(Duration::from_millis(10))
            .open_native()
            .map_err(|e| err(e.description))?;
        // Bytes the MCU sent to nobody (re-sent events, answers to a previous
        // session) would only be decoded and thrown away.
        serialport::SerialPort::clear(&port, serialport::ClearBuffer::Input)
            .map_err(|e| err(e.description))?;
        // SAFETY: the fd belongs to `port`, which outlives this borrow.
        let fd = unsafe { BorrowedFd::borrow_raw(port.as_raw_fd()) };
        let flags = fcntl(fd, FcntlArg::F_GETFL).map_err(|e| err(e.to_string()))?;
        let flags = OFlag::from_bits_truncate(flags) | OFlag::O_NONBLOCK;
        fcntl(fd, FcntlArg::F_SETFL(flags)).map_err(|e| err(e.to_string()))?;
        // SAFETY: TTYPort owns its fd for its whole life and always reports the same one.
        let fd = unsafe { AsyncFd::register(port) }.map_err(|e| err(e.to_string()))?;
        Ok(Self { fd })
    }
}

/// Run a std read/write on the raw fd without taking ownership of it.
fn with_file<R>(fd: RawFd, f: impl FnOnce(&mut File) -> R) -> R {
    // SAFETY: the fd stays owned by the TTYPort; ManuallyDrop never closes it.
    let mut file = ManuallyDrop::new(unsafe { File::from_raw_fd(fd) });
    f(&mut file)
}

/// A pseudo-terminal whose other side closed reads as EIO: that is end of stream.
fn eio_is_eof(r: io::Result<usize>) -> io::Result<usize> {
    match r {
        Err(e) if e.raw_os_error() == Some(nix::libc::EIO) => Ok(0),
        r => r,
    }
}

impl AsyncRead for SerialStream {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        loop {
            let mut guard = ready!(self.fd.poll_read_ready(cx))?;
            let unfilled = buf.initialize_unfilled();
            let r = guard
                .try_io(|fd| eio_is_eof(with_file(fd.get_ref().as_raw_fd(), |f| f.read(unfilled))));
            match r {
                Ok(Ok(n)) => {
                    buf.advance(n);
                    return Poll::Ready(Ok(()));
                }
                Ok(Err(e)) => return Poll::Ready(Err(e)),
                Err(_would_block) => continue,
            }
        }
    }
}

impl AsyncWrite for SerialStream {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        loop {
            let mut guard = ready!(self.fd.poll_write_ready(cx))?;
            match guard.try_io(|fd| with_file(fd.get_ref().as_raw_fd(), |f| f.write(buf))) {
                Ok(r) => return Poll::Ready(r),
                Err(_would_block) => continue,
            }
        }
    }

    fn poll_flush(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        // write(2) hands bytes to the tty layer; nothing is buffered here.
        Poll::Ready(Ok(()))
    }

    fn poll_shutdown(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }
}

/// A connector that (re)opens a serial device.
pub fn serial_connector(path: &str, baud: u32) -> Connector {
    let path = path.to_string();
    Arc::new(move || {
        let path = path.clone();
        Box::pin(async move { SerialStream::open(&path, baud).map(|s| Box::new(s) as BoxStream) })
    })
}
