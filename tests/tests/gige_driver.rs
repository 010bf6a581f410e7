//! The GigE Vision driver against the GigE Vision emulator on loopback: frames arrive
//! bit for bit as rendered, 8 and 16 bit; lost packets are resent or the frame is
//! refused as incomplete; a camera that stops answering heartbeats, a second client,
//! and a camera in another pixel format give clear errors.

use crate::gige_common;

use drivers::{Camera, DriverError};
use emulators::gige::GigeConfig;
use gige_common::*;
use protocol::Pixels;

#[test]
fn frames_received_equal_frames_rendered_bit_for_bit() {
    let rt = runtime();
    rt.block_on(async {
        let rig = rig(None, None);
        rig.lock().unwrap().machine_mut().home();
        let emu = emulator(&rig, GigeConfig::default()).await;
        let mut cam = connect(&emu, options()).await;
        let info = cam.info().clone();
        assert_eq!((info.width, info.height, info.bit_depth), (1280, 1024, 8));
        assert_eq!(info.model, "XYGateway SimMono");
        assert_eq!(info.serial, "SIM0001");
        for k in 0..2u64 {
            // The same rig state renders the same frame (the noise seed follows the
            // frame counter): render it here from a copy, then grab over GigE.
            let expected = rig.lock().unwrap().clone().grab().0;
            let f = cam.grab().await.unwrap();
            assert_eq!(f.meta.sequence, k);
            assert!(
                f.image == expected,
                "frame {k} differs from the rendered one"
            );
            assert_eq!(f.meta.exposure_us, 2000.0);
        }
        assert_eq!(emu.frames_sent(), 2);
    });
}

#[test]
fn mono16_frames_arrive_bit_for_bit() {
    let rt = runtime();
    rt.block_on(async {
        let rig = rig(Some((320, 240)), Some(16));
        let emu = emulator(&rig, GigeConfig::default()).await;
        let mut cam = connect(&emu, options()).await;
        assert_eq!(cam.info().bit_depth, 16);
        let expected = rig.lock().unwrap().clone().grab().0;
        let f = cam.grab().await.unwrap();
        assert!(matches!(f.image.pixels, Pixels::Mono16(_)));
        assert!(f.image == expected);
    });
}

#[test]
fn lost_packets_are_resent_and_the_frame_is_exact() {
    let rt = runtime();
    rt.block_on(async {
        let rig = rig(Some((640, 480)), None);
        let emu = emulator(
            &rig,
            GigeConfig {
                drop_every: Some(5),
                ..Default::default()
            },
        )
        .await;
        let mut opts = options();
        opts.packet_size = 1500;
        opts.packet_timeout = std::time::Duration::from_millis(50);
        let mut cam = connect(&emu, opts).await;
        for _ in 0..2 {
            let expected = rig.lock().unwrap().clone().grab().0;
            let f = cam.grab().await.unwrap();
            assert!(f.image == expected);
        }
    });
}

#[test]
fn packets_lost_for_good_give_an_incomplete_frame_error_never_a_frame() {
    let rt = runtime();
    rt.block_on(async {
        let rig = rig(Some((640, 480)), None);
        let emu = emulator(
            &rig,
            GigeConfig {
                drop_every: Some(7),
                loss_on_resend: true,
                ..Default::default()
            },
        )
        .await;
        let mut opts = options();
        opts.packet_size = 1500;
        opts.packet_timeout = std::time::Duration::from_millis(50);
        opts.resend_rounds = 2;
        let mut cam = connect(&emu, opts).await;
        let e = cam.grab().await.unwrap_err();
        let m = e.to_string();
        assert!(matches!(e, DriverError::Protocol { .. }), "{m}");
        assert!(m.contains("incomplete frame"), "{m}");
        assert!(m.contains("payload packets missing (ids 7,14,"), "{m}");
        assert!(m.contains("frame refused"), "{m}");
        // Without resend the same loss is reported straight away.
        let mut opts = options();
        opts.packet_size = 1500;
        opts.resend_rounds = 0;
        drop(cam);
        let emu2 = emulator(
            &rig,
            GigeConfig {
                drop_every: Some(7),
                ..Default::default()
            },
        )
        .await;
        let mut cam = connect(&emu2, opts).await;
        let m = cam.grab().await.unwrap_err().to_string();
        assert!(m.contains("incomplete frame"), "{m}");
    });
}

#[test]
fn a_camera_that_stops_answering_heartbeats_is_an_error() {
    let rt = runtime();
    rt.block_on(async {
        let rig = rig(Some((160, 120)), None);
        let emu = emulator(&rig, GigeConfig::default()).await;
        let mut opts = options();
        // Heartbeats every 200 ms (a third of the timeout the driver sets).
        opts.heartbeat_timeout_ms = Some(600);
        let mut cam = connect(&emu, opts).await;
        cam.grab().await.unwrap();
        emu.set_silent(true);
        // The trigger itself goes unanswered, or the heartbeat has already noticed.
        let e = cam.grab().await.unwrap_err();
        let m = e.to_string();
        assert!(matches!(e, DriverError::Timeout { .. }), "{m}");
        assert!(
            m.contains("TriggerSoftware") || m.contains("stopped answering heartbeats"),
            "{m}"
        );
    });
}

#[test]
fn a_second_client_is_refused_while_the_first_has_control() {
    let rt = runtime();
    rt.block_on(async {
        let rig = rig(Some((160, 120)), None);
        let emu = emulator(&rig, GigeConfig::default()).await;
        let _first = connect(&emu, options()).await;
        let e = drivers::gige::GigeCamera::open(&emu.control_addr().to_string(), options())
            .await
            .err()
            .expect("second client refused");
        assert!(
            e.to_string().contains("another client controls the camera"),
            "{e}"
        );
    });
}

#[test]
fn nothing_listening_is_a_timeout_naming_the_address() {
    let rt = runtime();
    rt.block_on(async {
        let sock = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        let addr = sock.local_addr().unwrap();
        let e = drivers::gige::GigeCamera::open(&addr.to_string(), options())
            .await
            .err()
            .expect("no camera");
        let m = e.to_string();
        assert!(
            m.contains(&addr.to_string()) && m.contains("no answer"),
            "{m}"
        );
    });
}

#[test]
fn frames_of_another_size_or_pixel_format_than_declared_are_refused() {
    let rt = runtime();
    rt.block_on(async {
        let rig = rig(Some((160, 120)), None);
        let emu = emulator(&rig, GigeConfig::default()).await;
        let mut cam = connect(&emu, options()).await;
        cam.grab().await.unwrap();
        // The camera changes behind the driver's back: another width...
        rig.lock().unwrap().camera_mut().width = 200;
        let m = cam.grab().await.unwrap_err().to_string();
        assert!(
            m.contains("is 200x120 Mono8 but the camera declared 160x120 Mono8")
                && m.contains("frame refused"),
            "{m}"
        );
        // ...then another pixel format.
        {
            let mut r = rig.lock().unwrap();
            r.camera_mut().width = 160;
            r.camera_mut().bit_depth = 16;
        }
        let m = cam.grab().await.unwrap_err().to_string();
        assert!(
            m.contains("160x120 Mono16 but the camera declared 160x120 Mono8"),
            "{m}"
        );
        // Back as declared: frames flow again.
        rig.lock().unwrap().camera_mut().bit_depth = 8;
        cam.grab().await.unwrap();
    });
}

#[test]
fn a_zipped_genicam_xml_is_read_like_a_plain_one() {
    let rt = runtime();
    rt.block_on(async {
        let rig = rig(Some((160, 120)), None);
        let emu = emulator(
            &rig,
            GigeConfig {
                zip_xml: true,
                ..Default::default()
            },
        )
        .await;
        let mut cam = connect(&emu, options()).await;
        assert_eq!((cam.info().width, cam.info().height), (160, 120));
        let expected = rig.lock().unwrap().clone().grab().0;
        assert!(cam.grab().await.unwrap().image == expected);
    });
}

/// Frame timestamps follow the camera's device clock (wall time here, at the rate the
/// tick frequency registers declare), not the simulated machine's clock: a client that
/// divides by the tick frequency gets wall time. The bounds are causal (the trigger
/// happened after the server started and within the grab), never a timing guess.
#[test]
fn frame_timestamps_follow_the_device_clock_and_its_declared_tick_rate() {
    let rt = runtime();
    rt.block_on(async {
        let rig = rig(Some((320, 240)), None);
        // An hour of simulated machine time: a timestamp taken from the simulation's
        // clock would be far outside the bounds below.
        rig.lock().unwrap().machine_mut().advance(3600.0);
        for scale in [1.0, 25.0] {
            let before_start = std::time::Instant::now();
            let emu = emulator(
                &rig,
                GigeConfig {
                    clock: world::Clock::Scaled(scale),
                    ..Default::default()
                },
            )
            .await;
            let after_start = std::time::Instant::now();
            let mut cam = connect(&emu, options()).await;
            let mut last = 0;
            for _ in 0..3 {
                let grab_start = before_start.elapsed().as_nanos() as u64;
                let f = cam.grab().await.unwrap();
                let grab_end = before_start.elapsed().as_nanos() as u64;
                let slack = (after_start - before_start).as_nanos() as u64;
                let t = f.meta.timestamp_ns;
                assert!(
                    t + slack >= grab_start && t <= grab_end,
                    "scale {scale}: timestamp {t} ns outside the grab [{grab_start}, {grab_end}] ns"
                );
                assert!(t > last, "timestamps increase");
                last = t;
            }
        }
    });
}

#[test]
fn spoofed_stream_packets_from_another_address_are_dropped_and_counted() {
    use protocol::gige::gvsp::{Content, ImageLeader, Packet};
    use protocol::gige::pfnc;
    let rt = runtime();
    rt.block_on(async {
        let rig = rig(Some((160, 120)), None);
        let emu = emulator(&rig, GigeConfig::default()).await;
        let mut cam = connect(&emu, options()).await;
        let target = cam.stream_addr().unwrap();
        // Anyone on the camera network: leaders of absurd frames for the block ids the
        // camera is about to use, queued on the stream port before each real frame.
        let spoofer = tokio::net::UdpSocket::bind("127.0.0.1:0").await.unwrap();
        for _ in 0..2 {
            for block_id in 1..=4u16 {
                let mut b = Vec::new();
                Packet {
                    status: 0,
                    block_id,
                    packet_id: 0,
                    content: Content::Leader(ImageLeader {
                        timestamp: 0,
                        pixel_format: pfnc::MONO8,
                        width: 65535,
                        height: 65535,
                        offset_x: 0,
                        offset_y: 0,
                    }),
                }
                .encode(&mut b);
                spoofer.send_to(&b, target).await.unwrap();
            }
            let expected = rig.lock().unwrap().clone().grab().0;
            let f = cam.grab().await.unwrap();
            assert!(f.image == expected);
        }
        assert!(cam.stray_packets() > 0, "no spoofed packet was counted");
    });
}
