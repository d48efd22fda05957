//! Sans-IO protocol cores: ATI serial records and commands, Net F/T RDT, DAQ framing.

use proptest::prelude::*;
use rig_core::ft::daq::{DaqFrame, DaqParser, FRAME_LEN, crc16_ccitt};
use rig_core::ft::netft::{Arrival, RdtCommand, RdtRecord, RdtRequest, SequenceTracker};
use rig_core::ft::serial::{
    Command, CountsRecord, OutputMode, SerialEvent, SerialParser, plausible_counts,
};
use rig_core::ft::{NANO17_SI_25_MAX, SampleFlags, saturation_mask};

fn limits() -> [i32; 6] {
    plausible_counts(&NANO17_SI_25_MAX, 320.0, 64.0, 1.5)
}

fn records(p: &mut SerialParser) -> Vec<CountsRecord> {
    let mut out = Vec::new();
    while let Some(e) = p.next_event() {
        if let SerialEvent::Record(r) = e {
            out.push(r);
        }
    }
    out
}

#[test]
fn ft_serial_commands_encode_as_the_controller_expects() {
    assert_eq!(Command::OutputAscii.encode(), b"CD A\r");
    assert_eq!(Command::OutputBinary.encode(), b"CD B\r");
    assert_eq!(Command::OutputResolved.encode(), b"CD R\r");
    assert_eq!(Command::QueryStream.encode(), b"QS\r");
    assert_eq!(Command::StopStream.encode(), b"\r");
    assert_eq!(Command::Bias.encode(), b"SB\r");
    assert_eq!(Command::Averaging(8).encode(), b"SA 8\r");
    assert_eq!(Command::parse("sa 16"), Some(Command::Averaging(16)));
    assert_eq!(Command::parse("cd  b"), Some(Command::OutputBinary));
    assert_eq!(Command::parse("XYZ"), None);
}

#[test]
fn ft_serial_ascii_records_garbage_and_truncation_are_counted_and_resynchronised() {
    let mut p = SerialParser::new(OutputMode::Ascii, limits());
    let r1 = CountsRecord {
        status: 0,
        counts: [12, -5, -3200, 40, -41, 7],
    };
    let r2 = CountsRecord {
        status: 3,
        counts: [0, 1, 2, 3, 4, 5],
    };
    let mut bytes = b"QS\r\n".to_vec();
    bytes.extend(r1.encode_ascii());
    bytes.extend(b"\x01\xfe#@!garbage\r\n"); // a garbage line
    bytes.extend(b"    0,    12,   -5\r\n"); // a truncated record
    bytes.extend(b"zz\xff,1,2,3,4,5,6\r\n"); // garbage glued to a record
    bytes.extend(r2.encode_ascii());
    bytes.extend(b"\r\n>");
    // Feed in awkward pieces.
    for chunk in bytes.chunks(7) {
        p.push(chunk);
    }
    let mut got = Vec::new();
    let mut prompts = 0;
    let mut texts = Vec::new();
    while let Some(e) = p.next_event() {
        match e {
            SerialEvent::Record(r) => got.push(r),
            SerialEvent::Prompt => prompts += 1,
            SerialEvent::Text(t) => texts.push(t),
        }
    }
    assert_eq!(got, vec![r1, r2]);
    assert_eq!(prompts, 1);
    assert_eq!(texts, vec!["QS".to_string()]);
    let s = p.stats();
    assert_eq!(s.records, 2);
    assert_eq!(s.truncated_records, 1);
    assert_eq!(s.garbage_lines, 2);
    assert_eq!(r1.to_wrench(320.0, 64.0)[2], -10.0);
}

#[test]
fn ft_serial_binary_locks_after_the_qs_echo_and_relocks_after_garbage() {
    let mut p = SerialParser::new(OutputMode::Binary, limits());
    let recs: Vec<CountsRecord> = (0..40)
        .map(|k| CountsRecord {
            status: 0,
            counts: [k, -k, -3000 + k, 100, -100, 5 * k],
        })
        .collect();
    let mut bytes = b"QS\r\n".to_vec();
    for r in &recs[..20] {
        bytes.extend(r.encode_binary());
    }
    bytes.extend([0x7f, 0xff, 0x80, 0x01, 0x7f]); // 5 garbage bytes mid-stream
    for r in &recs[20..] {
        bytes.extend(r.encode_binary());
    }
    p.push(&bytes);
    let got = records(&mut p);
    assert_eq!(&got[..20], &recs[..20]);
    // Everything after the garbage is recovered once relocked; nothing implausible got through.
    assert!(got.len() >= 38, "{}", got.len());
    assert_eq!(got.last(), recs.last());
    assert!(
        p.stats().bad_binary_records >= 1 && p.stats().skipped_bytes >= 5,
        "{:?}",
        p.stats()
    );
}

#[test]
fn ft_rdt_request_and_record_roundtrip_big_endian() {
    let req = RdtRequest {
        command: RdtCommand::StartRealtime,
        sample_count: 0,
    };
    assert_eq!(req.encode(), [0x12, 0x34, 0x00, 0x02, 0, 0, 0, 0]);
    let bias = RdtRequest {
        command: RdtCommand::SetSoftwareBias,
        sample_count: 0,
    };
    assert_eq!(bias.encode()[2..4], [0x00, 0x42]);
    assert_eq!(RdtRequest::decode(&req.encode()).unwrap(), req);
    assert!(RdtRequest::decode(&[0x43, 0x21, 0, 2, 0, 0, 0, 0]).is_err());
    let rec = RdtRecord {
        rdt_sequence: u32::MAX,
        ft_sequence: 7,
        status: 0x8000_0000,
        counts: [1_000_000, -2, 3, -4_000, 5, i32::MIN],
    };
    let b = rec.encode();
    assert_eq!(b.len(), 36);
    assert_eq!(&b[0..4], &[0xff; 4]);
    assert_eq!(RdtRecord::decode(&b).unwrap(), rec);
    assert_eq!(rec.to_wrench(1e6, 1e3)[0], 1.0);
    assert_eq!(rec.to_wrench(1e6, 1e3)[3], -4.0);
    let mut two = b.to_vec();
    two.extend(b);
    assert_eq!(RdtRecord::decode_datagram(&two).unwrap().count(), 2);
    assert!(RdtRecord::decode_datagram(&two[..50]).is_err());
}

#[test]
fn ft_rdt_tracker_counts_loss_reorder_duplicates_across_wrap() {
    let mut t = SequenceTracker::new();
    let start = u32::MAX - 3;
    let seq = |k: u32| start.wrapping_add(k);
    assert_eq!(t.observe(seq(0)), Arrival::First);
    assert_eq!(t.observe(seq(1)), Arrival::InOrder);
    assert_eq!(t.observe(seq(3)), Arrival::AfterGap { missing: 1 }); // 2 missing
    assert_eq!(t.observe(seq(2)), Arrival::Late); // 2 arrives late: reordered, not lost
    assert_eq!(t.observe(seq(4)), Arrival::InOrder); // wraps through 0
    assert_eq!(t.observe(seq(8)), Arrival::AfterGap { missing: 3 }); // 5, 6, 7 missing
    assert_eq!(t.observe(seq(8)), Arrival::Duplicate);
    assert_eq!(t.observe(seq(6)), Arrival::Late);
    assert_eq!(t.observe(seq(6)), Arrival::Duplicate);
    let s = t.stats();
    assert_eq!(
        (s.received, s.lost, s.reordered, s.duplicates),
        (9, 2, 2, 2)
    );
}

#[test]
fn ft_sequence_unwraps_across_the_u32_wrap_for_every_arrival() {
    let mut t = SequenceTracker::new();
    let start = u32::MAX - 1;
    let first = u64::from(start);
    assert_eq!(t.observe_unwrapped(start), (Arrival::First, first));
    assert_eq!(t.observe_unwrapped(u32::MAX), (Arrival::InOrder, first + 1));
    // 0 and 1 lost across the wrap; 2 is the fourth number.
    assert_eq!(
        t.observe_unwrapped(2),
        (Arrival::AfterGap { missing: 2 }, first + 4)
    );
    assert_eq!(t.observe_unwrapped(0), (Arrival::Late, first + 2));
    assert_eq!(t.observe_unwrapped(2), (Arrival::Duplicate, first + 4));
    // From before the first number: the same u32 arithmetic, near u64::MAX below zero.
    let mut t = SequenceTracker::new();
    assert_eq!(t.observe_unwrapped(0), (Arrival::First, 0));
    assert_eq!(t.observe_unwrapped(u32::MAX).1, u64::MAX);
}

proptest! {
    #[test]
    fn ft_rdt_tracker_is_exact_for_any_local_shuffle_and_drop(
        start in any::<u32>(),
        n in 50u32..400,
        drops in prop::collection::vec(any::<bool>(), 400),
        swaps in prop::collection::vec(0usize..400, 0..40),
    ) {
        // Sequence numbers start..start+n, some dropped, some adjacent pairs swapped.
        let mut sent: Vec<u32> = (0..n).filter(|&k| k == 0 || !drops[k as usize] || k % 3 != 0).map(|k| start.wrapping_add(k)).collect();
        let lost_expected = n as u64 - sent.len() as u64;
        let mut reordered_expected = 0u64;
        let mut swapped = vec![false; sent.len()];
        for s in swaps {
            // Keep the first packet first, and never touch a packet twice, so "late" is exact.
            if s >= 1 && s + 1 < sent.len() && !swapped[s] && !swapped[s + 1] {
                sent.swap(s, s + 1);
                swapped[s] = true;
                swapped[s + 1] = true;
                reordered_expected += 1;
            }
        }
        // The newest packet must be the last one for lost counts to be final.
        let newest = start.wrapping_add(n - 1);
        if sent.last() != Some(&newest) {
            // A dropped or swapped last packet: account for it.
            if let Some(pos) = sent.iter().position(|&x| x == newest) {
                sent.remove(pos);
                sent.push(newest);
                if swapped[pos] { reordered_expected -= 1; }
            } else {
                return Ok(());
            }
        }
        let mut t = SequenceTracker::new();
        for &s in &sent { t.observe(s); }
        let st = t.stats();
        prop_assert_eq!(st.lost, lost_expected);
        prop_assert_eq!(st.reordered, reordered_expected);
        prop_assert_eq!(st.duplicates, 0);
    }

    #[test]
    fn ft_parsers_never_panic_on_random_bytes(bytes in prop::collection::vec(any::<u8>(), 0..2000), split in 1usize..64) {
        let mut a = SerialParser::new(OutputMode::Ascii, limits());
        let mut b = SerialParser::new(OutputMode::Binary, limits());
        b.begin_binary_stream();
        let mut d = DaqParser::new();
        for c in bytes.chunks(split) {
            a.push(c); b.push(c); d.push(c);
            while a.next_event().is_some() {}
            while b.next_event().is_some() {}
            while d.next_frame().is_some() {}
        }
        let _ = RdtRecord::decode_datagram(&bytes);
        let _ = RdtRequest::decode(&bytes);
    }
}

fn frame(k: u32) -> DaqFrame {
    DaqFrame {
        sequence: k,
        device_time_us: 1000 * k,
        gauges_uv: [123_100, -87_200, 2_204_400, -150_700, 61_300, -9_999_999],
        thermistor_uv: 1_273_400,
        status: 0,
    }
}

#[test]
fn ft_daq_crc_is_ccitt_false_and_frames_roundtrip() {
    assert_eq!(crc16_ccitt(b"123456789"), 0x29B1);
    let f = frame(7);
    let b = f.encode();
    assert_eq!(b.len(), FRAME_LEN);
    assert_eq!(&b[0..2], &[0xA5, 0x5A]);
    assert_eq!(DaqFrame::decode(&b), Some(f));
    assert!((f.gauges_v()[2] - 2.2044).abs() < 1e-12);
    assert!((f.thermistor_v().unwrap() - 1.2734).abs() < 1e-12);
}

#[test]
fn ft_daq_parser_counts_garbage_crc_failures_and_truncation_exactly() {
    let mut bytes = Vec::new();
    bytes.extend(frame(0).encode());
    bytes.extend(b"noise!!"); // 7 garbage bytes (no 0xA5 in them)
    bytes.extend(frame(1).encode());
    let mut bad = frame(2).encode();
    bad[20] ^= 0x5a; // checksum failure
    bytes.extend(bad);
    bytes.extend(&frame(3).encode()[..20]); // truncated: the next frame starts at once
    bytes.extend(frame(4).encode());
    bytes.extend(frame(5).encode());
    let mut p = DaqParser::new();
    let mut got = Vec::new();
    for c in bytes.chunks(13) {
        p.push(c);
        while let Some(f) = p.next_frame() {
            got.push(f.sequence);
        }
    }
    assert_eq!(got, vec![0, 1, 4, 5]);
    let s = p.stats();
    assert_eq!(
        (s.frames, s.garbage_bytes, s.crc_errors, s.truncated),
        (4, 7, 1, 1),
        "{s:?}"
    );
}

#[test]
fn ft_saturation_mask_and_flags() {
    let m = saturation_mask(&[25.0, -1.0, -40.0, 0.0, f64::NAN, 10.0], &NANO17_SI_25_MAX);
    assert_eq!(m, 0b010101);
    let mut f = SampleFlags::NONE;
    f.set_saturated_axes(m);
    assert!(f.contains(SampleFlags::SATURATED));
    assert_eq!(f.saturated_axes(), m);
    assert_eq!(f.to_string(), "saturated(Fx,Fz,Ty)");
}
