//! One TensorBoard event file: TFRecord framing around `tensorboard.Event` messages.
//!
//! A record is `u64` length (little-endian), the masked CRC-32C of those 8 bytes, the
//! encoded `Event`, and the masked CRC-32C of the event: the format of TensorFlow's
//! `tensorflow/core/lib/io/record_writer.cc`, which TensorBoard's `event_file_loader`
//! reads. The first event names the format version (`brain.Event:2`).

use ess_proto::tensorboard::{
    Event, SessionLog, Summary, SummaryMetadata, TensorProto, TensorShapeProto, event, session_log,
    summary, summary_metadata, tensor_shape_proto,
};
use prost::Message;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};
use thiserror::Error;

/// A failure to write an event file; names the file.
#[derive(Debug, Error)]
#[error("{path}: {source}")]
pub struct EventFileError {
    /// The event file (or the directory it was to be created in).
    pub path: PathBuf,
    /// The I/O error.
    #[source]
    pub source: std::io::Error,
}

/// CRC-32C (Castagnoli), as TFRecord checksums its parts.
const CRC32C: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISCSI);

/// TFRecord's masked CRC: the CRC rotated right by 15 bits plus a constant, so that a
/// CRC of data holding CRCs stays well spread.
pub fn masked_crc(bytes: &[u8]) -> u32 {
    let c = CRC32C.checksum(bytes);
    c.rotate_right(15).wrapping_add(0xa282_ead8)
}

/// `data` framed as one TFRecord.
pub fn frame(data: &[u8]) -> Vec<u8> {
    let len = (data.len() as u64).to_le_bytes();
    let mut out = Vec::with_capacity(data.len() + 16);
    out.extend_from_slice(&len);
    out.extend_from_slice(&masked_crc(&len).to_le_bytes());
    out.extend_from_slice(data);
    out.extend_from_slice(&masked_crc(data).to_le_bytes());
    out
}

fn now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// The machine's name for the file name (TensorBoard's own writers put it there too).
fn host() -> String {
    let name = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default();
    let name: String = name
        .trim()
        .chars()
        .filter(|c| c.is_ascii_alphanumeric() || *c == '-')
        .collect();
    if name.is_empty() {
        "localhost".into()
    } else {
        name
    }
}

/// A summary value carrying a plugin's tensor (text).
fn text_value(tag: &str, text: &str) -> summary::Value {
    let tensor = TensorProto {
        dtype: 7, // DT_STRING
        tensor_shape: Some(TensorShapeProto {
            dim: vec![tensor_shape_proto::Dim {
                size: 1,
                name: String::new(),
            }],
            unknown_rank: false,
        }),
        string_val: vec![text.as_bytes().to_vec()],
        ..Default::default()
    };
    summary::Value {
        tag: tag.into(),
        metadata: Some(SummaryMetadata {
            plugin_data: Some(summary_metadata::PluginData {
                plugin_name: "text".into(),
                content: Vec::new(),
            }),
            ..Default::default()
        }),
        value: Some(summary::value::Value::Tensor(tensor)),
        ..Default::default()
    }
}

/// Width and height from a PNG's header, `None` if `png` is not one.
pub fn png_size(png: &[u8]) -> Option<(i32, i32)> {
    const MAGIC: &[u8] = b"\x89PNG\r\n\x1a\n";
    if png.len() < 24 || &png[..8] != MAGIC || &png[12..16] != b"IHDR" {
        return None;
    }
    let be = |b: &[u8]| i32::from_be_bytes([b[0], b[1], b[2], b[3]]);
    Some((be(&png[16..20]), be(&png[20..24])))
}

/// An open event file.
pub struct EventFile {
    path: PathBuf,
    out: BufWriter<File>,
}

impl EventFile {
    /// A new event file in `dir` (created if missing), named as TensorBoard's writers
    /// name theirs (`events.out.tfevents.<seconds>.<host>.<pid>.<n>`), with the
    /// version record written.
    pub fn create(dir: &Path) -> Result<Self, EventFileError> {
        let err = |path: &Path| {
            let path = path.to_path_buf();
            move |source| EventFileError { path, source }
        };
        std::fs::create_dir_all(dir).map_err(err(dir))?;
        let secs = now() as u64;
        let (pid, mut n) = (std::process::id(), 0);
        let (file, path) = loop {
            let name = format!("events.out.tfevents.{secs:010}.{}.{pid}.{n}", host());
            let path = dir.join(name);
            match File::options().write(true).create_new(true).open(&path) {
                Ok(f) => break (f, path),
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => n += 1,
                Err(e) => return Err(err(&path)(e)),
            }
        };
        let mut f = Self {
            path,
            out: BufWriter::new(file),
        };
        f.write(None, event::What::FileVersion("brain.Event:2".into()))?;
        f.flush()?;
        Ok(f)
    }

    /// The file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn write(&mut self, step: Option<i64>, what: event::What) -> Result<(), EventFileError> {
        let e = Event {
            wall_time: now(),
            step: step.unwrap_or(0),
            source_metadata: None,
            what: Some(what),
        };
        let rec = frame(&e.encode_to_vec());
        self.out.write_all(&rec).map_err(|source| EventFileError {
            path: self.path.clone(),
            source,
        })
    }

    /// Scalars at `step`, one event.
    pub fn scalars(&mut self, step: i64, values: &[(String, f64)]) -> Result<(), EventFileError> {
        let value = values
            .iter()
            .map(|(tag, v)| summary::Value {
                tag: tag.clone(),
                value: Some(summary::value::Value::SimpleValue(*v as f32)),
                ..Default::default()
            })
            .collect();
        self.write(Some(step), event::What::Summary(Summary { value }))
    }

    /// Markdown text under `tag` at `step` (TensorBoard's text plugin).
    pub fn text(&mut self, step: i64, tag: &str, markdown: &str) -> Result<(), EventFileError> {
        let value = vec![text_value(tag, markdown)];
        self.write(Some(step), event::What::Summary(Summary { value }))
    }

    /// A PNG image under `tag` at `step`; `false` (nothing written) if `png` is not a
    /// PNG.
    pub fn image(&mut self, step: i64, tag: &str, png: &[u8]) -> Result<bool, EventFileError> {
        let Some((width, height)) = png_size(png) else {
            return Ok(false);
        };
        let image = summary::Image {
            height,
            width,
            colorspace: 4, // RGBA; TensorBoard reads the PNG itself
            encoded_image_string: png.to_vec(),
        };
        let value = vec![summary::Value {
            tag: tag.into(),
            value: Some(summary::value::Value::Image(image)),
            ..Default::default()
        }];
        self.write(Some(step), event::What::Summary(Summary { value }))?;
        Ok(true)
    }

    /// A restart at `step` (a resumed run): TensorBoard drops what earlier files of
    /// this directory logged after it, as the resumed run repeats those steps.
    pub fn restart(&mut self, step: i64) -> Result<(), EventFileError> {
        let log = SessionLog {
            status: session_log::SessionStatus::Start as i32,
            checkpoint_path: String::new(),
            msg: String::new(),
        };
        self.write(Some(step), event::What::SessionLog(log))
    }

    /// Pushes what was written to the file, so a running TensorBoard sees it.
    pub fn flush(&mut self) -> Result<(), EventFileError> {
        self.out.flush().map_err(|source| EventFileError {
            path: self.path.clone(),
            source,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn masked_crc_matches_tensorboards_own() {
        // CRC-32C check value (RFC 3720 B.4): "123456789" -> 0xE3069283; the masked
        // values as TensorBoard's `pywrap_tensorflow.masked_crc32c` computes them.
        assert_eq!(CRC32C.checksum(b"123456789"), 0xE306_9283);
        assert_eq!(masked_crc(b"123456789"), 0xC78A_B0E5);
        assert_eq!(masked_crc(b""), 0xA282_EAD8);
    }

    #[test]
    fn a_record_frames_its_length_and_data_with_their_checksums() {
        let r = frame(b"abc");
        assert_eq!(r.len(), 8 + 4 + 3 + 4);
        assert_eq!(&r[..8], &3u64.to_le_bytes());
        assert_eq!(&r[8..12], &masked_crc(&3u64.to_le_bytes()).to_le_bytes());
        assert_eq!(&r[12..15], b"abc");
        assert_eq!(&r[15..], &masked_crc(b"abc").to_le_bytes());
    }

    #[test]
    fn png_size_reads_the_header_and_refuses_other_bytes() {
        let mut png = b"\x89PNG\r\n\x1a\n\0\0\0\x0dIHDR".to_vec();
        png.extend_from_slice(&640u32.to_be_bytes());
        png.extend_from_slice(&480u32.to_be_bytes());
        assert_eq!(png_size(&png), Some((640, 480)));
        assert_eq!(png_size(b"GIF89a........................"), None);
    }

    #[test]
    fn a_file_starts_with_the_version_record() {
        let dir = tempfile::tempdir().expect("tempdir");
        let f = EventFile::create(&dir.path().join("tb")).expect("create");
        let bytes = std::fs::read(f.path()).expect("read");
        let len = u64::from_le_bytes(bytes[..8].try_into().expect("8 bytes")) as usize;
        let e = Event::decode(&bytes[12..12 + len]).expect("event");
        assert_eq!(
            e.what,
            Some(event::What::FileVersion("brain.Event:2".into()))
        );
        let name = f.path().file_name().and_then(|n| n.to_str()).expect("name");
        assert!(name.starts_with("events.out.tfevents."), "{name}");
    }
}
