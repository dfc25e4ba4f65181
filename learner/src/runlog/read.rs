//! Reading a run log back ([`read`]): streaming, every complete message of a possibly
//! truncated file.

use super::record::{PROTOBUF, Record, TOPICS};
use super::{RunLogError, scene};
use ess_proto::pb;
use std::fs::File;
use std::io::Read;
use std::path::Path;

/// One message read back, with its log time.
#[derive(Debug, Clone, PartialEq)]
pub struct Logged {
    /// Log time (ns since the Unix epoch).
    pub log_time: u64,
    /// The message.
    pub record: Record,
}

/// Everything [`read`] could recover from a run log.
#[derive(Debug, Clone, Default)]
pub struct RunLogContents {
    /// Every complete message in file order.
    pub records: Vec<Logged>,
    /// Why reading stopped before the end of a complete file (a truncated or damaged
    /// file: everything before the first unreadable record is in `records`); `None`
    /// for an intact file.
    pub truncated: Option<String>,
    /// Messages on topics this version does not know (skipped).
    pub unknown: usize,
    /// The `/scene` and `/tf` messages, undecoded (Ess only writes them).
    pub scene: Vec<SceneMessage>,
}

/// One `/scene` or `/tf` message as read.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneMessage {
    /// How many records precede it in the file.
    pub after: usize,
    /// Index into [`scene::SCENE_TOPICS`].
    pub topic: usize,
    /// Its log time.
    pub log_time: u64,
    /// The encoded message.
    pub data: Vec<u8>,
}

impl RunLogContents {
    /// The records without their times.
    pub fn messages(&self) -> impl Iterator<Item = &Record> {
        self.records.iter().map(|l| &l.record)
    }

    /// The last `/config` record.
    pub fn config(&self) -> Option<&pb::RunConfig> {
        self.records.iter().rev().find_map(|l| match &l.record {
            Record::Config(c) => Some(c),
            _ => None,
        })
    }
}

/// The longest record (or decompressed chunk) the reader accepts. The largest Ess
/// writes is a `/train/chunk` sample: well under 1 MiB even for Humanoid.
pub const MAX_RECORD_BYTES: usize = 256 << 20;

/// Reads the run log at `path`, streaming, and returns every complete message; a
/// truncated file is no error (see [`RunLogContents::truncated`]). Errors: the file
/// cannot be opened, does not start with the MCAP magic, has a known topic with a
/// foreign schema, or a complete message that does not decode.
pub fn read(path: &Path) -> Result<RunLogContents, RunLogError> {
    let file = File::open(path).map_err(|source| RunLogError::Io {
        path: path.to_path_buf(),
        what: "opening the run log",
        source,
    })?;
    read_from(path, std::io::BufReader::new(file))
}

/// [`read`] over any reader; `path` names it in errors.
pub fn read_from(path: &Path, mut source: impl Read) -> Result<RunLogContents, RunLogError> {
    let io = |source| RunLogError::Io {
        path: path.to_path_buf(),
        what: "reading the run log",
        source,
    };
    let mut head = Vec::with_capacity(mcap::MAGIC.len());
    (&mut source)
        .take(mcap::MAGIC.len() as u64)
        .read_to_end(&mut head)
        .map_err(io)?;
    if !mcap::MAGIC.starts_with(&head) {
        return Err(RunLogError::NotMcap {
            path: path.to_path_buf(),
        });
    }
    let mut out = RunLogContents::default();
    if head.len() < mcap::MAGIC.len() {
        out.truncated = Some(format!("the file ends after {} bytes", head.len()));
        return Ok(out);
    }
    // A corrupt length field must be an error, not an allocation of exabytes (which
    // aborts the process): no record Ess writes comes near the limit.
    let options =
        mcap::sans_io::LinearReaderOptions::default().with_record_length_limit(MAX_RECORD_BYTES);
    let reader = mcap::io::MessageReader::new_with_options(
        std::io::Cursor::new(head).chain(source),
        options,
    );
    for (index, msg) in reader.enumerate() {
        let msg = match msg {
            Ok(m) => m,
            Err(e) => {
                out.truncated = Some(e.to_string());
                break;
            }
        };
        let ch = &msg.channel;
        let Some(kind) = TOPICS.iter().position(|(t, _)| *t == ch.topic) else {
            // The 3D scene is for viewers: kept as bytes, with its place among the
            // records, so a resumed run's log carries it over; anything else is unknown.
            match scene::SCENE_TOPICS.iter().position(|(t, _)| *t == ch.topic) {
                Some(topic) => out.scene.push(SceneMessage {
                    after: out.records.len(),
                    topic,
                    log_time: msg.log_time,
                    data: msg.data.into_owned(),
                }),
                None => out.unknown += 1,
            }
            continue;
        };
        let expected = TOPICS[kind].1;
        let (found, schema_encoding) = ch
            .schema
            .as_ref()
            .map(|s| (s.name.clone(), s.encoding.clone()))
            .unwrap_or_default();
        if found != expected || schema_encoding != PROTOBUF || ch.message_encoding != PROTOBUF {
            return Err(RunLogError::WrongSchema {
                path: path.to_path_buf(),
                topic: ch.topic.clone(),
                found: ess_proto::text::printable(&format!(
                    "schema `{found}` (schema encoding `{schema_encoding}`, message encoding `{}`)",
                    ch.message_encoding
                ))
                .into_owned(),
                expected,
            });
        }
        let record = Record::decode(kind, &msg.data).map_err(|source| RunLogError::Decode {
            path: path.to_path_buf(),
            topic: ch.topic.clone(),
            index,
            schema: expected,
            source,
        })?;
        out.records.push(Logged {
            log_time: msg.log_time,
            record,
        });
    }
    Ok(out)
}
