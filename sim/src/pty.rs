//! The emulated rig on a pseudo-terminal, so another process opens it as a
//! real serial port (`/dev/pts/N`, e.g. with the `serialport` crate).
//!
//! [`serve_pty`] opens a pty pair, puts the slave side in raw mode (no echo,
//! no line editing, 8-bit clean), and serves the master side from a thread
//! that runs the rig in real time (times `speed`). The server keeps its own
//! descriptor of the slave open, so a client may open and close the device
//! as often as it likes; bytes the MCU sends while nobody reads wait in the
//! terminal's buffer, and once that is full they are dropped, as on a UART.
//! A disconnect fault (or [`PtyServer::stop`]) closes the master: the client
//! sees a hangup (reads fail or return EOF).

use std::fs::File;
use std::io::{ErrorKind, Read, Write};
use std::os::fd::{AsFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::thread::JoinHandle;
use std::time::Duration;

use nix::fcntl::{FcntlArg, OFlag, fcntl};
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::pty::openpty;
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};

use crate::link::RigHandle;
use crate::port::SimPort;
use crate::{SimConfig, SimError};

/// An emulated rig served on a pseudo-terminal. Dropping it stops the server.
#[derive(Debug)]
pub struct PtyServer {
    path: PathBuf,
    handle: RigHandle,
    thread: Option<JoinHandle<()>>,
}

impl PtyServer {
    /// The slave device to open as a serial port.
    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn handle(&self) -> &RigHandle {
        &self.handle
    }

    /// Whether the server stopped (disconnect fault, or stopped).
    pub fn finished(&self) -> bool {
        self.thread.as_ref().is_none_or(|t| t.is_finished())
    }

    /// Stop serving and close the terminal.
    pub fn stop(mut self) {
        self.shutdown();
    }

    fn shutdown(&mut self) {
        self.handle.shutdown();
        if let Some(t) = self.thread.take() {
            // The thread only ends by returning; a panic there is already reported.
            let _ = t.join();
        }
    }
}

impl Drop for PtyServer {
    fn drop(&mut self) {
        self.shutdown();
    }
}

/// Start an emulated rig on a new pseudo-terminal.
pub fn serve_pty(cfg: &SimConfig) -> Result<PtyServer, SimError> {
    cfg.validate()?;
    let port = SimPort::new(cfg.rig.clone(), cfg.link)?;
    let handle = RigHandle::new(port, cfg.speed, cfg.host_lead_us);
    let pty = openpty(None, None).map_err(|e| SimError::Pty("openpty", e))?;
    let mut t = tcgetattr(pty.slave.as_fd()).map_err(|e| SimError::Pty("tcgetattr", e))?;
    cfmakeraw(&mut t);
    tcsetattr(pty.slave.as_fd(), SetArg::TCSANOW, &t).map_err(|e| SimError::Pty("tcsetattr", e))?;
    let path = nix::unistd::ttyname(pty.slave.as_fd()).map_err(|e| SimError::Pty("ttyname", e))?;
    let flags =
        fcntl(pty.master.as_fd(), FcntlArg::F_GETFL).map_err(|e| SimError::Pty("fcntl", e))?;
    fcntl(
        pty.master.as_fd(),
        FcntlArg::F_SETFL(OFlag::from_bits_truncate(flags) | OFlag::O_NONBLOCK),
    )
    .map_err(|e| SimError::Pty("fcntl", e))?;
    let h = handle.clone();
    let thread = std::thread::Builder::new()
        .name("sim-pty".into())
        .spawn(move || serve_master(File::from(pty.master), pty.slave, h))
        .map_err(SimError::Io)?;
    Ok(PtyServer {
        path,
        handle,
        thread: Some(thread),
    })
}

/// The server loop: returns when stopped, on a disconnect fault, or on an
/// unrecoverable terminal error.
fn serve_master(mut master: File, slave: OwnedFd, handle: RigHandle) {
    let mut buf = [0u8; 1024];
    while !handle.stopped() {
        let (out, wait, closed) = handle.service();
        if closed {
            break;
        }
        if !out.is_empty() {
            // Non-blocking: what does not fit in the terminal's buffer is lost.
            match master.write(&out) {
                Ok(_) => {}
                Err(e) if e.kind() == ErrorKind::WouldBlock => {}
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(_) => break,
            }
        }
        let ms = if wait.is_zero() {
            0u8
        } else {
            wait.as_millis().clamp(1, 10) as u8
        };
        let mut fds = [PollFd::new(master.as_fd(), PollFlags::POLLIN)];
        match poll(&mut fds, PollTimeout::from(ms)) {
            Ok(n) if n > 0 => match master.read(&mut buf) {
                Ok(0) => std::thread::sleep(Duration::from_millis(1)),
                Ok(n) => handle.host_wrote(&buf[..n]),
                Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::Interrupted) => {}
                // EIO: no slave open (cannot happen while we hold one); wait.
                Err(_) => std::thread::sleep(Duration::from_millis(1)),
            },
            Ok(_) => {}
            Err(nix::errno::Errno::EINTR) => {}
            Err(_) => break,
        }
    }
    // Closing the master hangs up the client.
    drop(master);
    drop(slave);
}

/// `qhm sim --pty`: serve an emulated rig on a pseudo-terminal, write its
/// path as one line to `out`, and serve until Ctrl-C (or a disconnect fault).
pub async fn serve_pty_until_ctrl_c(
    cfg: &SimConfig,
    out: &mut (dyn Write + Send),
) -> Result<(), SimError> {
    let server = serve_pty(cfg)?;
    writeln!(out, "{}", server.path().display()).map_err(SimError::Io)?;
    out.flush().map_err(SimError::Io)?;
    let ctrl_c = tokio::signal::ctrl_c();
    tokio::pin!(ctrl_c);
    loop {
        tokio::select! {
            r = &mut ctrl_c => {
                r.map_err(SimError::Io)?;
                break;
            }
            _ = tokio::time::sleep(Duration::from_millis(100)) => {
                if server.finished() {
                    break;
                }
            }
        }
    }
    server.stop();
    Ok(())
}
