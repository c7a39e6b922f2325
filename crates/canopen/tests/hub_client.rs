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
    let e = ehactl_canopen::bus::open(
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
