//! The Rust socketcand client against the in-process hub.

use ehactl_canopen::hub::Hub;
use ehactl_canopen::socketcand::SocketcandBus;
use ehactl_canopen::{BusErrorKind, CanBus, CanFrame};
use std::io::{Read, Write};
use std::time::Duration;

fn start_hub() -> u16 {
    let hub = Hub::bind("127.0.0.1:0", true).unwrap();
    let port = hub.local_addr().unwrap().port();
    std::thread::spawn(move || hub.serve());
    port
}

#[test]
fn frames_cross_the_hub_both_ways_without_echo() {
    let port = start_hub();
    let t = Duration::from_secs(2);
    let mut a = SocketcandBus::connect("127.0.0.1", port, "can0", t).unwrap();
    let mut b = SocketcandBus::connect("127.0.0.1", port, "can0", t).unwrap();
    let frames = [
        CanFrame::std(0x080, []),
        CanFrame::std(0x230, [0x00, 0x40]),
        CanFrame::std(0x630, [0x2B, 0x17, 0x10, 0x00, 0x14, 0x00, 0x00, 0x00]),
    ];
    for f in &frames {
        a.send(f).unwrap();
    }
    for f in &frames {
        assert_eq!(b.recv_timeout(t).unwrap(), Some(*f));
    }
    assert_eq!(a.recv_timeout(Duration::from_millis(100)).unwrap(), None);
    b.send(&frames[1]).unwrap();
    assert_eq!(a.recv_timeout(t).unwrap(), Some(frames[1]));
    assert_eq!(a.try_recv().unwrap(), None);
}

#[test]
fn handshake_errors_and_closed_connections_are_reported() {
    // A server that greets wrongly.
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = l.local_addr().unwrap().port();
    std::thread::spawn(move || {
        let (mut s, _) = l.accept().unwrap();
        s.write_all(b"< hello >").unwrap();
        let (mut s2, _) = l.accept().unwrap();
        s2.write_all(b"< hi >").unwrap();
        let mut buf = [0u8; 64];
        let _ = s2.read(&mut buf);
        s2.write_all(b"< ok >").unwrap();
        let _ = s2.read(&mut buf);
        s2.write_all(b"< ok >< frame 1A0 1.0 0102 >< frame 1A0 1.0 01 02 >")
            .unwrap();
        drop(s2);
        drop(s);
    });
    let t = Duration::from_secs(2);
    let e = SocketcandBus::connect("127.0.0.1", port, "can0", t)
        .err()
        .unwrap();
    assert_eq!(e.kind, BusErrorKind::Protocol);
    assert!(
        e.message.contains("expected `< hi >`, got `< hello >`"),
        "{e}"
    );
    let mut bus = SocketcandBus::connect("127.0.0.1", port, "can0", t).unwrap();
    assert_eq!(
        bus.recv_timeout(t).unwrap(),
        Some(CanFrame::std(0x1A0, [1, 2]))
    );
    let e = bus.recv_timeout(t).unwrap_err();
    assert_eq!(e.kind, BusErrorKind::Protocol);
    assert!(e.message.contains("contiguous"), "{e}");
    let e = bus.recv_timeout(t).unwrap_err();
    assert_eq!(e.kind, BusErrorKind::Closed, "{e}");
}

#[test]
fn nobody_listening_is_a_clear_open_error() {
    let port = {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        l.local_addr().unwrap().port()
    };
    let e = SocketcandBus::connect("127.0.0.1", port, "can0", Duration::from_secs(1))
        .err()
        .unwrap();
    assert_eq!(e.kind, BusErrorKind::Open);
    assert!(e.message.contains("cannot connect"), "{e}");
}

#[test]
fn socketcan_without_af_can_is_an_error_not_a_panic() {
    let e = ehactl_canopen::transport::open(
        &ehactl_canopen::BusUrl::parse("socketcan://can0").unwrap(),
        Duration::from_secs(1),
    )
    .err()
    .unwrap();
    assert!(
        matches!(e.kind, BusErrorKind::Unsupported | BusErrorKind::Open),
        "{e}"
    );
    assert!(e.message.contains("socketcan://can0"), "{e}");
}

/// A raw socketcand client that completes the handshake into rawmode and then never reads.
fn stalled_client(port: u16) -> std::net::TcpStream {
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
    let mut buf = [0u8; 64];
    let mut expect = |s: &mut std::net::TcpStream, want: &[u8]| {
        let n = s.read(&mut buf).unwrap();
        assert_eq!(&buf[..n], want);
    };
    expect(&mut s, b"< hi >");
    s.write_all(b"< open can0 >").unwrap();
    expect(&mut s, b"< ok >");
    s.write_all(b"< rawmode >").unwrap();
    expect(&mut s, b"< ok >");
    s
}

#[test]
fn clients_that_do_not_read_are_dropped_and_counted_and_hold_up_no_one() {
    let hub = Hub::bind("127.0.0.1:0", true)
        .unwrap()
        .with_join_delay(Duration::from_millis(20));
    let port = hub.local_addr().unwrap().port();
    let stats = hub.stats();
    std::thread::spawn(move || hub.serve());
    let t = Duration::from_secs(2);
    let mut a = SocketcandBus::connect("127.0.0.1", port, "can0", t).unwrap();
    let mut b = SocketcandBus::connect("127.0.0.1", port, "can0", t).unwrap();
    let stalled: Vec<_> = (0..3).map(|_| stalled_client(port)).collect();
    std::thread::sleep(Duration::from_millis(100)); // past every join delay
                                                    // Enough frames to fill the stalled clients' socket buffers and then their queues. The
                                                    // sender keeps at most WINDOW frames ahead of the healthy reader (a CAN bus is slower
                                                    // than this loopback relay anyway), so the healthy client is never the one that lags.
    const N: u32 = 400_000;
    const WINDOW: u32 = 1000;
    let received = std::sync::Arc::new(std::sync::atomic::AtomicU32::new(0));
    let rc = received.clone();
    let reader = std::thread::spawn(move || {
        let mut got = 0u32;
        while got < N {
            match b.recv_timeout(Duration::from_secs(5)).unwrap() {
                Some(f) => {
                    assert_eq!(u32::from_le_bytes(f.data[..4].try_into().unwrap()), got);
                    got += 1;
                    rc.store(got, std::sync::atomic::Ordering::Release);
                }
                None => panic!("healthy client starved after {got} of {N} frames"),
            }
        }
        got
    });
    let t0 = std::time::Instant::now();
    for k in 0..N {
        while k >= received.load(std::sync::atomic::Ordering::Acquire) + WINDOW {
            std::thread::yield_now();
        }
        a.send(&CanFrame::std(0x181, k.to_le_bytes())).unwrap();
    }
    assert_eq!(reader.join().unwrap(), N, "every frame, in order");
    let dt = t0.elapsed();
    assert_eq!(
        stats
            .clients_dropped
            .load(std::sync::atomic::Ordering::Relaxed),
        3
    );
    // each stalled connection was shut down by the hub: reading it ends (EOF or reset)
    for mut s in stalled {
        s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        let mut sink = Vec::new();
        let _ = s.read_to_end(&mut sink);
    }
    eprintln!("{N} frames through the hub with 3 stalled clients in {dt:?}");
}

#[test]
fn client_text_in_log_lines_is_sanitised() {
    use ehactl_canopen::hub::sanitize;
    assert_eq!(sanitize("< open can0 >"), "< open can0 >");
    assert_eq!(sanitize("a\u{1b}[2Jb\nc\r"), "a\\x1B[2Jb\\x0Ac\\x0D");
    assert_eq!(sanitize("µ"), "\\u{B5}");
    let long = "x".repeat(500);
    assert_eq!(sanitize(&long), format!("{}…", "x".repeat(80)));
}
