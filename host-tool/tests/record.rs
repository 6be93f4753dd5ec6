//! The recorder: nothing recorded is lost or duplicated across disconnects, restarts of
//! `driftid record` and a recorder killed mid-write; damaged frames cost only themselves and are
//! counted; the raw log holds every byte received; a recording of another run is not mixed in.

use std::io::{self, Read, Write};
use std::path::PathBuf;

use host_tool::link::record::{record_with, RecordOptions};
use host_tool::recording::read_recording;
use protocol::{Config, Encoder, Hello, Message, RawSample};

fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("driftid-record-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// One connection of a scripted firmware: its bytes in reads of 37, then "port gone".
struct Conn {
    bytes: Vec<u8>,
    at: usize,
}
impl Read for Conn {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        if self.at >= self.bytes.len() {
            return Err(io::Error::from(io::ErrorKind::BrokenPipe));
        }
        let n = buf.len().min(37).min(self.bytes.len() - self.at);
        buf[..n].copy_from_slice(&self.bytes[self.at..self.at + n]);
        self.at += n;
        Ok(n)
    }
}
impl Write for Conn {
    fn write(&mut self, b: &[u8]) -> io::Result<usize> {
        Ok(b.len()) // the recorder's Ping
    }
    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

fn sample(k: u32) -> RawSample {
    let t = f64::from(k);
    RawSample {
        seq: k,
        t_s: t,
        specific_force: [1e-3 * (t * 0.01).sin(), -2e-3 * t / 1000.0, 9.8 + 1e-6 * t],
        temp_c: f64::NAN,
    }
}

fn hello(lat: f64) -> Message {
    Message::Hello(Hello {
        board: protocol::Board::Host,
        firmware: [0, 1, 0],
        state_dim: 15,
        config: Config {
            latitude_deg: lat,
            ..Config::default()
        },
    })
}

/// Frames of Hello + samples `ks`; `damage(k, frame)` may alter a sample's frame.
fn stream(
    enc: &mut Encoder,
    lat: f64,
    ks: impl Iterator<Item = u32>,
    damage: impl Fn(u32, &mut Vec<u8>),
) -> Vec<u8> {
    let mut out = enc.frame(hello(lat)).unwrap().to_vec();
    for k in ks {
        let mut f = enc.frame(Message::Raw(sample(k))).unwrap().to_vec();
        damage(k, &mut f);
        out.extend(f);
    }
    out
}

fn options(dir: &std::path::Path) -> RecordOptions {
    RecordOptions {
        port: "scripted".into(),
        baud: 0,
        out: dir.join("run.csv"),
        raw: Some(dir.join("run.bin")),
        latitude_deg: None,
        duration: None,
        reconnect: true,
        force: false,
    }
}

fn run(
    opts: &RecordOptions,
    conns: Vec<Vec<u8>>,
) -> anyhow::Result<host_tool::link::record::RecordSummary> {
    let mut conns = conns.into_iter();
    let mut open = move || -> anyhow::Result<Option<Conn>> {
        Ok(conns.next().map(|bytes| Conn { bytes, at: 0 }))
    };
    record_with(opts, &mut open, |_| {})
}

#[test]
fn disconnects_restarts_and_a_killed_recorder_lose_and_duplicate_nothing() {
    let dir = temp_dir("resume");
    let opts = options(&dir);
    let mut enc = Encoder::new();
    // Recorder 1, connection 1: samples 0..=120, the link drops in the middle of sample 120's frame.
    let mut c1 = stream(&mut enc, 39.1, 0..=120, |_, _| {});
    c1.truncate(c1.len() - 20);
    // Connection 2 (the port came back; the firmware resends from 100): 100..=180, sample 150's
    // frame damaged by a bit flip.
    let c2 = stream(&mut enc, 39.1, 100..=180, |k, f| {
        if k == 150 {
            f[10] ^= 0x04;
        }
    });
    let sum = run(&opts, vec![c1.clone(), c2.clone()]).unwrap();
    // 0..=119 from connection 1, then 120..=180 except the damaged 150; 100..=119 were resent.
    assert_eq!(sum.connections, 2);
    assert_eq!(sum.samples, 120 + 61 - 1);
    assert_eq!(sum.duplicates, 20);
    // Frames lost: the one cut by the disconnect (ended by the next connection's delimiter) and
    // the damaged one — each counted, nothing else.
    assert_eq!(sum.rx.decoder.bad(), 2, "{}", sum.rx);

    // The recorder is killed in the middle of writing a row.
    let csv = dir.join("run.csv");
    let mut f = std::fs::OpenOptions::new().append(true).open(&csv).unwrap();
    f.write_all(b"181.0,0.00018,-3.6e-").unwrap();
    drop(f);

    // Recorder 2 on the same files: the firmware streams 170..=250.
    let c3 = stream(&mut enc, 39.1, 170..=250, |_, _| {});
    let sum2 = run(&opts, vec![c3.clone()]).unwrap();
    assert_eq!(sum2.resumed_samples, 180);
    assert_eq!(
        sum2.repairs.len(),
        1,
        "the partial row is cut off and reported"
    );
    assert!(
        sum2.repairs[0].contains("run.csv:") && sum2.repairs[0].contains("partial last line"),
        "{}",
        sum2.repairs[0]
    );
    assert_eq!(
        (sum2.samples, sum2.duplicates),
        (70, 11),
        "181..=250 appended, 170..=180 skipped"
    );

    // The recording: every sample 0..=250 exactly once, in order, bit-exact, except the damaged 150.
    let rec = read_recording(&csv).unwrap();
    assert!(rec.repairs.is_empty());
    let want: Vec<u32> = (0..=250).filter(|&k| k != 150).collect();
    assert_eq!(rec.samples.len(), want.len());
    for (s, &k) in rec.samples.iter().zip(&want) {
        let w = sample(k);
        assert_eq!(
            (s.t_s, s.specific_force_mps2),
            (w.t_s, w.specific_force),
            "sample {k}"
        );
    }
    assert_eq!(rec.meta.latitude_deg, Some(39.1));
    // The raw log: every byte received, in order, over both recorders.
    let raw = std::fs::read(dir.join("run.bin")).unwrap();
    assert_eq!(raw, [c1, c2, c3].concat());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_recording_of_another_run_is_not_mixed_and_a_broken_one_not_appended_to() {
    let dir = temp_dir("mismatch");
    let opts = options(&dir);
    let mut enc = Encoder::new();
    run(&opts, vec![stream(&mut enc, 39.1, 0..=10, |_, _| {})]).unwrap();
    let before = std::fs::read(&opts.out).unwrap();
    // Another firmware configuration (latitude) on the same --out: refused.
    let e = run(&opts, vec![stream(&mut enc, 45.0, 11..=20, |_, _| {})]).unwrap_err();
    let msg = format!("{e:#}");
    assert!(msg.contains("run.csv") && msg.contains("latitude"), "{msg}");
    assert_eq!(
        std::fs::read(&opts.out).unwrap(),
        before,
        "nothing appended"
    );
    // A file that breaks the format (bad number on line 5): refused with file and line.
    let text = String::from_utf8(before)
        .unwrap()
        .replacen("\n3.0,", "\nx3.0,", 1);
    std::fs::write(&opts.out, &text).unwrap();
    let e = run(&opts, vec![stream(&mut enc, 39.1, 11..=20, |_, _| {})]).unwrap_err();
    let msg = format!("{e:#}");
    assert!(
        msg.contains("run.csv:") && msg.contains("cannot be appended"),
        "{msg}"
    );
    assert_eq!(
        std::fs::read_to_string(&opts.out).unwrap(),
        text,
        "the broken file is left as it was"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A NaN/∞ or out-of-range sample in the stream used to stop the recorder (its writer refused the
/// row with an error) and lose everything after it. Now each is skipped and counted by the
/// reader's own rules, recording goes on, and the file reads back with every other sample.
#[test]
fn a_nonfinite_or_out_of_range_sample_is_skipped_and_counted() {
    let dir = temp_dir("nonfinite");
    let opts = options(&dir);
    let mut enc = Encoder::new();
    let mut bytes = enc.frame(hello(39.1)).unwrap().to_vec();
    let bad = [5u32, 9, 12, 20];
    for k in 0..=30u32 {
        let mut s = sample(k);
        match k {
            5 => s.specific_force[0] = f64::NAN,
            9 => s.t_s = f64::INFINITY,
            12 => s.specific_force[2] = f64::NEG_INFINITY,
            // Finite, but beyond the reader's |a| limit (1000 m/s²): the reader would refuse it.
            20 => s.specific_force[1] = 2000.0,
            _ => {}
        }
        bytes.extend(enc.frame(Message::Raw(s)).unwrap());
    }
    let sum = run(&opts, vec![bytes]).unwrap();
    assert_eq!((sum.nonfinite, sum.out_of_range), (3, 1), "each counted");
    assert_eq!(sum.samples, 31 - 4, "every other sample written");
    assert_eq!(
        (sum.duplicates, sum.sample_gaps),
        (0, 0),
        "skipped is not lost"
    );
    assert!(
        sum.first_skipped
            .as_deref()
            .is_some_and(|s| s.contains("sample 5")),
        "{:?}",
        sum.first_skipped
    );
    let rec = read_recording(&opts.out).expect("the reader accepts what record wrote");
    let want: Vec<f64> = (0..=30u32)
        .filter(|k| !bad.contains(k))
        .map(f64::from)
        .collect();
    let got: Vec<f64> = rec.samples.iter().map(|s| s.t_s).collect();
    assert_eq!(got, want);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Metadata the recording format refuses (a latitude outside [-90, 90], an implausible gravity)
/// used to be written as announced by the firmware, giving a file the reader then refused. Now
/// each is checked by the reader's rules, left out with a note, and `--latitude-deg` fills in.
#[test]
fn metadata_the_reader_would_refuse_is_not_written() {
    let dir = temp_dir("badmeta");
    let mut opts = options(&dir);
    opts.latitude_deg = Some(45.0);
    let mut enc = Encoder::new();
    let h = Message::Hello(Hello {
        board: protocol::Board::Host,
        firmware: [0, 1, 0],
        state_dim: 15,
        config: Config {
            latitude_deg: 120.0,
            gravity_mps2: Some(50.0),
            ..Config::default()
        },
    });
    let mut bytes = enc.frame(h).unwrap().to_vec();
    for k in 0..10 {
        bytes.extend(enc.frame(Message::Raw(sample(k))).unwrap());
    }
    let sum = run(&opts, vec![bytes]).unwrap();
    assert_eq!(sum.samples, 10);
    assert_eq!(sum.notes.len(), 2, "{:?}", sum.notes);
    assert!(sum.notes[0].contains("latitude_deg") && sum.notes[0].contains("120"));
    assert!(sum.notes[1].contains("gravity_mps2") && sum.notes[1].contains("50"));
    let rec = read_recording(&opts.out).expect("the reader accepts what record wrote");
    assert_eq!(rec.meta.latitude_deg, Some(45.0), "from --latitude-deg");
    assert_eq!(
        rec.meta.gravity_mps2, None,
        "left out: normal gravity is used"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 28, item 1: `record --raw old.csv` appended binary frames to an existing recording,
/// which then no longer read; and `--out notes.txt` (not a recording) had its last line cut off
/// before the recorder found it was not a recording. Now a `--raw` file that is not a raw frame
/// log is refused (naming it and `--force`) and neither file changes by a byte; with `--force`
/// it is replaced, never appended to.
#[test]
fn the_raw_log_is_never_appended_to_a_file_that_is_not_one() {
    let dir = temp_dir("raw-foreign");
    let mut opts = options(&dir);
    let old = dir.join("old.csv");
    let text = "# latitude_deg: 39.1\nt_s,ax_mps2,ay_mps2,az_mps2\n0,0,0,9.8\n1,0,0,9.8\n";
    std::fs::write(&old, text).unwrap();
    opts.raw = Some(old.clone());
    let mut enc = Encoder::new();
    let c = stream(&mut enc, 39.1, 0..=10, |_, _| {});
    let err = format!("{:#}", run(&opts, vec![c.clone()]).unwrap_err());
    assert!(err.contains("old.csv") && err.contains("--force"), "{err}");
    assert_eq!(
        std::fs::read_to_string(&old).unwrap(),
        text,
        "the recording is untouched"
    );
    assert!(
        !dir.join("run.csv").exists(),
        "nothing recorded when an output is refused"
    );

    // --out a text file with no final newline: not a recording, refused, not cut.
    let notes = dir.join("notes.txt");
    std::fs::write(&notes, "shopping list\nmilk").unwrap();
    let mut o = options(&dir);
    o.out = notes.clone();
    o.raw = None;
    assert!(run(&o, vec![c.clone()]).is_err());
    assert_eq!(
        std::fs::read_to_string(&notes).unwrap(),
        "shopping list\nmilk"
    );

    // With --force the file is replaced by the raw log (not appended to).
    opts.force = true;
    run(&opts, vec![c.clone()]).unwrap();
    assert_eq!(std::fs::read(&old).unwrap(), c);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 28, item 3: a firmware that changed its latitude mid-stream went on being recorded into
/// the same file. Now the recorder stops, naming both latitudes, and the file keeps the first run.
#[test]
fn a_latitude_change_mid_stream_stops_the_recorder_by_name() {
    let dir = temp_dir("latitude-change");
    let opts = options(&dir);
    let mut enc = Encoder::new();
    let mut bytes = stream(&mut enc, 39.1, 0..=10, |_, _| {});
    bytes.extend(stream(&mut enc, 45.0, 11..=20, |_, _| {}));
    let e = format!("{:#}", run(&opts, vec![bytes]).unwrap_err());
    assert!(
        e.contains("latitude 39.1 deg")
            && e.contains("reports 45 deg")
            && e.contains("keeps the first run (11 samples"),
        "{e}"
    );
    let rec = read_recording(&opts.out).unwrap();
    assert_eq!(rec.samples.len(), 11, "only the first run");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 28, item 3: a firmware that restarted its clock ended as two runs in one file, the
/// second's first samples called "duplicates". Now the recorder stops at the new run's first
/// sample, by name — whether its readings differ from the recorded ones or are the same (a
/// reboot is also seen in the link's sequence numbers starting again at 0).
#[test]
fn a_clock_restart_is_another_run_not_duplicates() {
    for same_readings in [false, true] {
        let dir = temp_dir(&format!("clock-restart-{same_readings}"));
        let opts = options(&dir);
        let mut enc = Encoder::new();
        let mut bytes = stream(&mut enc, 39.1, 0..=30, |_, _| {});
        if same_readings {
            // The firmware rebooted: its link numbering starts again at 0, its samples too.
            bytes.extend(stream(&mut Encoder::new(), 39.1, 0..=40, |_, _| {}));
        } else {
            // The same link, the clock back at 0, other readings.
            for k in 0..=40u32 {
                let mut s = sample(k);
                s.specific_force[0] += 1e-4;
                bytes.extend(enc.frame(Message::Raw(s)).unwrap());
            }
        }
        let e = format!("{:#}", run(&opts, vec![bytes]).unwrap_err());
        assert!(
            e.contains("went back from t_s = 30.0 s") && e.contains("another run"),
            "{same_readings}: {e}"
        );
        let rec = read_recording(&opts.out).unwrap();
        assert_eq!(rec.samples.len(), 31, "{same_readings}: only the first run");
        let _ = std::fs::remove_dir_all(&dir);
    }
}

/// Issue 28, item 3: a first sample without a temperature dropped the temp_c column for the
/// whole recording (the 89 temperatures after it lost, not counted). Now the column is always
/// there, empty where a sample has none, and those samples are counted.
#[test]
fn a_first_sample_without_temperature_keeps_the_column() {
    let dir = temp_dir("temp-column");
    let opts = options(&dir);
    let mut enc = Encoder::new();
    let mut bytes = enc.frame(hello(39.1)).unwrap().to_vec();
    for k in 0..90u32 {
        let mut s = sample(k);
        if k > 0 {
            s.temp_c = 20.0 + 0.01 * f64::from(k);
        }
        bytes.extend(enc.frame(Message::Raw(s)).unwrap());
    }
    let sum = run(&opts, vec![bytes]).unwrap();
    assert_eq!((sum.samples, sum.no_temp), (90, 1));
    let rec = read_recording(&opts.out).unwrap();
    assert!(rec.has_temp);
    let temps: Vec<Option<f64>> = rec.samples.iter().map(|s| s.temp_c).collect();
    assert_eq!(temps[0], None);
    for (k, t) in temps.iter().enumerate().skip(1) {
        assert_eq!(
            *t,
            Some(20.0 + 0.01 * k as f64),
            "sample {k}: written exactly"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 28, item 3: a sample stamped t = 1e308 was written, and the next 49 real samples were
/// dropped as "duplicates". Now an absurd time stamp (beyond any run, or out of line with its
/// neighbours) costs that sample only, named and counted.
#[test]
fn an_absurd_time_stamp_costs_only_itself() {
    let dir = temp_dir("absurd-time");
    let opts = options(&dir);
    let mut enc = Encoder::new();
    let mut bytes = enc.frame(hello(39.1)).unwrap().to_vec();
    for k in 0..100u32 {
        bytes.extend(enc.frame(Message::Raw(sample(k))).unwrap());
        let spike = match k {
            20 => Some(1e308),
            60 => Some(5000.0), // finite, plausible alone, but between 60 s and 61 s
            _ => None,
        };
        if let Some(t) = spike {
            let mut s = sample(1000 + k);
            s.t_s = t;
            bytes.extend(enc.frame(Message::Raw(s)).unwrap());
        }
    }
    let sum = run(&opts, vec![bytes]).unwrap();
    assert_eq!((sum.samples, sum.duplicates, sum.bad_times), (100, 0, 2));
    let first = sum.first_bad_time.unwrap();
    assert!(
        first.contains("sample 1020") && first.contains("1e308"),
        "{first}"
    );
    let rec = read_recording(&opts.out).unwrap();
    let times: Vec<f64> = rec.samples.iter().map(|s| s.t_s).collect();
    assert_eq!(times, (0..100).map(f64::from).collect::<Vec<_>>());
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 29, item 9: a recorder that received nothing said "0 samples to rec.csv" and exited 0.
/// Now it is an error saying what (did not) arrive, and no file is made — neither the recording
/// nor the raw log.
#[test]
fn receiving_nothing_is_an_error_and_makes_no_file() {
    let dir = temp_dir("nothing");
    let opts = options(&dir);
    let e = format!("{:#}", run(&opts, vec![Vec::new()]).unwrap_err());
    assert!(
        e.contains("nothing received") && e.contains("no sample recorded"),
        "{e}"
    );
    // Frames, but no sample (Hello only).
    let mut enc = Encoder::new();
    let e = format!(
        "{:#}",
        run(&opts, vec![enc.frame(hello(39.1)).unwrap().to_vec()]).unwrap_err()
    );
    assert!(
        e.contains("1 frames received") && e.contains("but no sample"),
        "{e}"
    );
    assert!(!opts.out.exists(), "no recording");
    let raw = std::fs::read(dir.join("run.bin")).unwrap();
    assert!(
        !raw.is_empty(),
        "the bytes that did arrive are in the raw log"
    );
    std::fs::remove_file(dir.join("run.bin")).unwrap();
    run(&opts, vec![Vec::new()]).unwrap_err();
    assert!(
        !dir.join("run.bin").exists(),
        "no byte received: no raw log"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
