//! Two processes through the pseudo-terminal: a child process serves the
//! emulated rig on a pty (as `qhm sim --pty` does), the parent opens the
//! device path as a serial port and speaks raw protocol frames to it.

use std::io::{BufRead, BufReader, Read, Write};
use std::process::{Command as Process, Stdio};
use std::time::{Duration, Instant};

use protocol::{
    Command, CommandError, Event, FrameDecoder, HostFrame, MAX_FRAME, McuFrame, Reply, encode_frame,
};

const CHILD_ENV: &str = "QHM_SIM_PTY_CHILD";

/// The child: serve a rig on a pty, print its path, serve until stdin closes.
#[test]
#[ignore = "the server half of two_processes_talk_through_the_pty, run by it"]
fn pty_server_child() {
    if std::env::var_os(CHILD_ENV).is_none() {
        return;
    }
    let server = sim::serve_pty(&sim::SimConfig::seeded(41)).expect("pty");
    println!("PTY {}", server.path().display());
    std::io::stdout().flush().expect("stdout");
    let mut line = String::new();
    let _ = std::io::stdin().read_line(&mut line);
    server.stop();
}

struct Serial {
    port: Box<dyn serialport::SerialPort>,
    dec: FrameDecoder,
    seq: u16,
    events: Vec<Event>,
}

impl Serial {
    fn call(&mut self, command: Command) -> Result<Reply, CommandError> {
        self.seq = self.seq.wrapping_add(1);
        let seq = self.seq;
        let mut buf = [0u8; MAX_FRAME];
        let n = encode_frame(&HostFrame { seq, command }, &mut buf).expect("fits");
        self.port.write_all(&buf[..n]).expect("write");
        let end = Instant::now() + Duration::from_secs(5);
        let mut rx = [0u8; 256];
        loop {
            assert!(Instant::now() < end, "no ack for {seq}");
            let got = match self.port.read(&mut rx) {
                Ok(n) => n,
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => 0,
                Err(e) => panic!("read: {e}"),
            };
            let mut reply = None;
            let events = &mut self.events;
            self.dec.push_slice::<McuFrame>(&rx[..got], |f| match f {
                Ok(McuFrame::Ack { seq: s, result }) if s == seq => reply = Some(result),
                Ok(McuFrame::Event { event, .. }) => events.push(event),
                _ => {}
            });
            if let Some(r) = reply {
                return r;
            }
        }
    }
}

#[test]
fn two_processes_talk_through_the_pty() {
    let exe = std::env::current_exe().expect("test binary");
    let mut child = Process::new(exe)
        .args(["pty_server_child", "--exact", "--ignored", "--nocapture"])
        .env(CHILD_ENV, "1")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("spawn the server process");
    let mut lines = BufReader::new(child.stdout.take().expect("stdout"));
    let path = loop {
        let mut line = String::new();
        let n = lines.read_line(&mut line).expect("child output");
        assert!(n > 0, "the server process exited without a path");
        if let Some(p) = line.trim().strip_prefix("PTY ") {
            break p.to_owned();
        }
    };
    assert!(path.starts_with("/dev/pts/"), "{path}");

    let port = serialport::new(&path, 115_200)
        .timeout(Duration::from_millis(20))
        .open()
        .expect("open the other process's pty");
    let mut s = Serial {
        port,
        dec: FrameDecoder::new(),
        seq: 0,
        events: Vec::new(),
    };
    let id = match s.call(Command::Identify) {
        Ok(Reply::Identity(id)) => id,
        other => panic!("{other:?}"),
    };
    assert_eq!(id.schema_hash, protocol::SCHEMA_HASH);
    assert_eq!(s.call(Command::Lamps { mask: 0x3c }), Ok(Reply::Ok));
    assert_eq!(
        s.call(Command::Trigger {
            mask: 0b10,
            pulse_us: 500
        }),
        Ok(Reply::Ok)
    );
    std::thread::sleep(Duration::from_millis(20));
    match s.call(Command::Status) {
        Ok(Reply::Status(st)) => {
            assert_eq!(st.lamps, 0x3c);
            assert_eq!(st.boot_id, id.boot_id);
        }
        other => panic!("{other:?}"),
    }
    assert!(s.events.contains(&Event::Booted {
        boot_id: id.boot_id,
        watchdog: false
    }));
    assert!(s.events.iter().any(|e| matches!(
        e,
        Event::TriggerFired {
            mask: 0b10,
            pulse_us: 500,
            ..
        }
    )));

    // Closing the child's stdin stops the server; the port hangs up.
    drop(child.stdin.take());
    let status = child.wait().expect("child exits");
    assert!(status.success(), "{status}");
    let mut buf = [0u8; 64];
    let end = Instant::now() + Duration::from_secs(5);
    loop {
        assert!(Instant::now() < end, "no hangup after the server stopped");
        match s.port.read(&mut buf) {
            Ok(0) => break,
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
            Err(_) => break,
            Ok(_) => {}
        }
    }
}
