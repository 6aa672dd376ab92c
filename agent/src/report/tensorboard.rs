//! TensorBoard event files for scalars, so `tensorboard --logdir runs` follows runs live.
//!
//! No maintained Rust crate writes them (tensorboard-rs was last released in 2022 and
//! drags in protobuf 2 and image codecs), and the subset needed is small:
//!
//! - the file is a TFRecord stream: per record, `len: u64 LE`, `masked_crc32c(len): u32
//!   LE`, `data`, `masked_crc32c(data): u32 LE`, where `masked(c) = ((c >> 15) | (c <<
//!   17)) + 0xa282_ead8` (tensorflow/core/lib/hash/crc32c.h);
//! - each record is a `tensorflow.Event` (event.proto): the first carries
//!   `file_version = "brain.Event:2"`, the others a `Summary` of `simple_value` scalars.
//!   A resumed run cuts the earlier files back to its checkpoint's records
//!   (`resume.rs`) rather than writing a `SessionLog` START, whose purge would also
//!   drop the records at the checkpoint's own step.
//!
//! The field numbers below are those of tensorboard/compat/proto/{event,summary}.proto.
//! `tests/tensorboard.rs` reads the files back with the `tensorboard` Python package.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use prost::Message;

/// `tensorflow.Event`, the fields a scalar writer uses.
#[derive(Clone, PartialEq, prost::Message)]
struct Event {
    #[prost(double, tag = "1")]
    wall_time: f64,
    #[prost(int64, tag = "2")]
    step: i64,
    #[prost(string, optional, tag = "3")]
    file_version: Option<String>,
    #[prost(message, optional, tag = "5")]
    summary: Option<Summary>,
}

/// `tensorflow.Summary`.
#[derive(Clone, PartialEq, prost::Message)]
struct Summary {
    #[prost(message, repeated, tag = "1")]
    value: Vec<SummaryValue>,
}

/// `tensorflow.Summary.Value` holding a `simple_value`.
#[derive(Clone, PartialEq, prost::Message)]
struct SummaryValue {
    #[prost(string, tag = "1")]
    tag: String,
    #[prost(float, optional, tag = "2")]
    simple_value: Option<f32>,
}

/// One named scalar at one step (tags use `/` to group charts: `train/return/task`).
#[derive(Debug, Clone, PartialEq)]
pub struct Scalar {
    /// Chart name.
    pub tag: String,
    /// Value (stored as float32, as TensorBoard does).
    pub value: f64,
}

impl Scalar {
    /// A scalar named `tag`.
    pub fn new(tag: impl Into<String>, value: f64) -> Self {
        Self {
            tag: tag.into(),
            value,
        }
    }
}

const CRC32C: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISCSI);

fn masked_crc(bytes: &[u8]) -> u32 {
    let c = CRC32C.checksum(bytes);
    c.rotate_right(15).wrapping_add(0xa282_ead8)
}

fn now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// Appends events to one `events.out.tfevents.<seconds>.<host>.<pid>` file.
#[derive(Debug)]
pub struct EventWriter {
    path: PathBuf,
    out: BufWriter<File>,
}

impl EventWriter {
    /// A new event file in `dir` (created if missing). A resumed run gets a second file
    /// in the same directory, which TensorBoard reads as one run.
    pub fn create(dir: &Path) -> std::io::Result<Self> {
        std::fs::create_dir_all(dir)?;
        let wall = now();
        let host = hostname();
        let path = dir.join(format!(
            "events.out.tfevents.{}.{host}.{}",
            wall as u64,
            std::process::id()
        ));
        let mut writer = Self {
            out: BufWriter::new(File::create(&path)?),
            path,
        };
        writer.record(&Event {
            wall_time: wall,
            step: 0,
            file_version: Some("brain.Event:2".into()),
            summary: None,
        })?;
        writer.flush()?;
        Ok(writer)
    }

    /// The file written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Write `scalars` as one event at `step`, stamped now.
    pub fn scalars(&mut self, step: u64, scalars: &[Scalar]) -> std::io::Result<()> {
        let value = scalars
            .iter()
            .map(|s| SummaryValue {
                tag: s.tag.clone(),
                simple_value: Some(s.value as f32),
            })
            .collect::<Vec<_>>();
        if value.is_empty() {
            return Ok(());
        }
        self.record(&Event {
            wall_time: now(),
            step: i64::try_from(step).unwrap_or(i64::MAX),
            file_version: None,
            summary: Some(Summary { value }),
        })
    }

    /// Push buffered events to the file (TensorBoard then shows them).
    pub fn flush(&mut self) -> std::io::Result<()> {
        self.out.flush()
    }

    fn record(&mut self, event: &Event) -> std::io::Result<()> {
        let data = event.encode_to_vec();
        let len = (data.len() as u64).to_le_bytes();
        self.out.write_all(&len)?;
        self.out.write_all(&masked_crc(&len).to_le_bytes())?;
        self.out.write_all(&data)?;
        self.out.write_all(&masked_crc(&data).to_le_bytes())
    }
}

fn hostname() -> String {
    let name = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .or_else(|_| std::fs::read_to_string("/etc/hostname"))
        .unwrap_or_default();
    let name: String = name
        .trim()
        .chars()
        .filter(|c| c.is_ascii_alphanumeric() || *c == '-' || *c == '_')
        .collect();
    if name.is_empty() {
        "localhost".into()
    } else {
        name
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc32c_matches_the_standard_check_value() {
        // CRC-32C of "123456789" is 0xE3069283 (the catalogue's check value for
        // CRC-32/ISCSI); masking is a 15-bit right rotation plus 0xa282ead8.
        assert_eq!(CRC32C.checksum(b"123456789"), 0xe306_9283);
        let expected = 0xe306_9283u32.rotate_right(15).wrapping_add(0xa282_ead8);
        assert_eq!(masked_crc(b"123456789"), expected);
    }

    #[test]
    fn records_are_length_framed_with_checksums() {
        let dir = tempfile::tempdir().unwrap();
        let mut w = EventWriter::create(dir.path()).unwrap();
        w.scalars(7, &[Scalar::new("a/b", 1.5)]).unwrap();
        w.flush().unwrap();
        let bytes = std::fs::read(w.path()).unwrap();
        let mut events = Vec::new();
        let mut at = 0;
        while at < bytes.len() {
            let len_bytes = &bytes[at..at + 8];
            let len = u64::from_le_bytes(len_bytes.try_into().unwrap()) as usize;
            let len_crc = u32::from_le_bytes(bytes[at + 8..at + 12].try_into().unwrap());
            assert_eq!(len_crc, masked_crc(len_bytes));
            let data = &bytes[at + 12..at + 12 + len];
            let data_crc =
                u32::from_le_bytes(bytes[at + 12 + len..at + 16 + len].try_into().unwrap());
            assert_eq!(data_crc, masked_crc(data));
            events.push(Event::decode(data).unwrap());
            at += 16 + len;
        }
        assert_eq!(events.len(), 2);
        assert_eq!(events[0].file_version.as_deref(), Some("brain.Event:2"));
        let summary = events[1].summary.as_ref().unwrap();
        assert_eq!(events[1].step, 7);
        assert_eq!(
            summary.value,
            vec![SummaryValue {
                tag: "a/b".into(),
                simple_value: Some(1.5)
            }]
        );
    }
}
