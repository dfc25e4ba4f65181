//! Content checksums of the safetensors files Ess writes and reads back: demonstrations,
//! experts, checkpoints, training states and replay buffers.
//!
//! safetensors checks a file's layout (header, offsets, sizes) but not its values, so a
//! flipped byte inside a tensor's data, or inside a metadata value such as the demos'
//! JSON, loaded silently. [`seal`] adds one metadata entry, `ess.sha256`: a JSON object
//! mapping each tensor's name to the SHA-256 of its dtype, shape and bytes, plus the key
//! `__metadata__` for the other metadata entries (sorted, length-prefixed). [`verify`]
//! recomputes them on load and names the first tensor (or the metadata) that differs.
//! Any flipped byte is caught: in the data by its tensor's hash; in the header JSON by
//! the parser (no flip of a byte turns JSON into other valid JSON with the same keys
//! except inside values), by a tensor's hash (dtype, shape, offsets) or by the metadata
//! hash.
//!
//! [`open`] is the one header check of Ess's own formats (demonstrations, experts): it
//! parses a file once, then checks its layout, `format`, `format_version` and seal.
//!
//! Files written before the seal existed have no `ess.sha256` entry. Only a caller that
//! can tell such a file by its own version number (demonstrations and experts of format
//! version 1) accepts it unsealed ([`Seal::Absent`]); every other file without a seal is
//! refused, so a flipped byte in the seal's own key cannot pass a file off as old: its
//! version still says it was sealed (and a flipped version leaves the seal in place).

use safetensors::tensor::{Dtype, SafeTensors, TensorView};
use sha2::{Digest, Sha256};
use std::collections::{BTreeMap, HashMap};

/// The metadata key holding the seal.
pub const KEY: &str = "ess.sha256";
/// The seal's entry for the metadata other than itself.
const METADATA: &str = "__metadata__";

/// What [`verify`] found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Seal {
    /// Every tensor and the metadata match their checksums.
    Verified,
    /// The file has no seal (written before Ess sealed its files).
    Absent,
}

/// A file whose content does not match its seal.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ChecksumError {
    /// Not parseable as safetensors at all.
    #[error("not a safetensors file (truncated or corrupt): {0}")]
    Layout(String),
    /// A tensor's bytes (or dtype or shape) differ from when it was written.
    #[error("tensor `{0}` does not match its checksum: the file is corrupt")]
    Tensor(String),
    /// The metadata entries differ from when they were written.
    #[error("the header metadata does not match its checksum: the file is corrupt")]
    Metadata,
    /// The seal names a tensor the file lacks, or misses one it has.
    #[error("tensor `{0}` is missing from the file or from its checksums: the file is corrupt")]
    Names(String),
    /// The file has no seal although it must.
    #[error("no `{KEY}` checksums in its header (written by an older Ess, or corrupt)")]
    Missing,
    /// The seal itself is not readable.
    #[error("the `{KEY}` header entry is not a map of checksums: the file is corrupt")]
    BadSeal,
}

/// Lower-case hex of a digest (the one spelling of SHA-256 sums in Ess's files).
pub fn hex(d: impl AsRef<[u8]>) -> String {
    d.as_ref().iter().map(|b| format!("{b:02x}")).collect()
}

/// A dtype's name as hashed: fixed here, so that no change of another crate's `Debug`
/// output invalidates files already written.
fn dtype_name(dtype: Dtype) -> String {
    match dtype {
        Dtype::BOOL => "BOOL".into(),
        Dtype::U8 => "U8".into(),
        Dtype::I8 => "I8".into(),
        Dtype::I16 => "I16".into(),
        Dtype::U16 => "U16".into(),
        Dtype::F16 => "F16".into(),
        Dtype::BF16 => "BF16".into(),
        Dtype::I32 => "I32".into(),
        Dtype::U32 => "U32".into(),
        Dtype::F32 => "F32".into(),
        Dtype::F64 => "F64".into(),
        Dtype::I64 => "I64".into(),
        Dtype::U64 => "U64".into(),
        other => format!("{other:?}"),
    }
}

/// SHA-256 of one tensor: dtype, rank, shape, then its bytes.
pub fn tensor_digest(dtype: Dtype, shape: &[usize], data: &[u8]) -> String {
    let mut h = Sha256::new();
    h.update(dtype_name(dtype).as_bytes());
    h.update((shape.len() as u64).to_le_bytes());
    for &d in shape {
        h.update((d as u64).to_le_bytes());
    }
    h.update(data);
    hex(h.finalize())
}

/// SHA-256 of the metadata entries other than the seal, sorted by key.
fn metadata_digest(metadata: &HashMap<String, String>) -> String {
    let sorted: BTreeMap<&String, &String> = metadata.iter().filter(|(k, _)| *k != KEY).collect();
    let mut h = Sha256::new();
    for (k, v) in sorted {
        for part in [k, v] {
            h.update((part.len() as u64).to_le_bytes());
            h.update(part.as_bytes());
        }
    }
    hex(h.finalize())
}

/// Adds the seal of `tensors` and of `metadata`'s other entries to `metadata`; call it
/// last, just before serializing.
pub fn seal<'a>(
    metadata: &mut HashMap<String, String>,
    tensors: impl IntoIterator<Item = (&'a str, &'a TensorView<'a>)>,
) {
    let mut sums: BTreeMap<String, String> = tensors
        .into_iter()
        .map(|(n, t)| (n.to_string(), tensor_digest(t.dtype(), t.shape(), t.data())))
        .collect();
    sums.insert(METADATA.into(), metadata_digest(metadata));
    let json = serde_json::to_string(&sums).unwrap_or_default();
    metadata.insert(KEY.into(), json);
}

/// Checks `bytes` (a whole safetensors file) against its seal. A file without one is
/// [`Seal::Absent`] when `legacy` says its version predates seals, an error otherwise.
pub fn verify(bytes: &[u8], legacy: bool) -> Result<Seal, ChecksumError> {
    let layout = |e: safetensors::SafeTensorError| ChecksumError::Layout(e.to_string());
    let st = SafeTensors::deserialize(bytes).map_err(layout)?;
    let (_, md) = SafeTensors::read_metadata(bytes).map_err(layout)?;
    let empty = HashMap::new();
    verify_parsed(&st, md.metadata().as_ref().unwrap_or(&empty), legacy)
}

/// [`verify`] on a file already parsed into its tensors and header metadata.
fn verify_parsed(
    st: &SafeTensors<'_>,
    metadata: &HashMap<String, String>,
    legacy: bool,
) -> Result<Seal, ChecksumError> {
    let layout = |e: safetensors::SafeTensorError| ChecksumError::Layout(e.to_string());
    let Some(json) = metadata.get(KEY) else {
        return if legacy {
            Ok(Seal::Absent)
        } else {
            Err(ChecksumError::Missing)
        };
    };
    let mut sums: BTreeMap<String, String> =
        serde_json::from_str(json).map_err(|_| ChecksumError::BadSeal)?;
    if sums.remove(METADATA).as_deref() != Some(metadata_digest(metadata).as_str()) {
        return Err(ChecksumError::Metadata);
    }
    let mut names: Vec<&str> = st.names();
    names.sort_unstable();
    for name in names {
        let t = st.tensor(name).map_err(layout)?;
        let want = sums
            .remove(name)
            .ok_or_else(|| ChecksumError::Names(name.to_string()))?;
        if want != tensor_digest(t.dtype(), t.shape(), t.data()) {
            return Err(ChecksumError::Tensor(name.to_string()));
        }
    }
    match sums.into_keys().next() {
        Some(extra) => Err(ChecksumError::Names(extra)),
        None => Ok(Seal::Verified),
    }
}

/// The versions of one of Ess's file formats that a build reads.
#[derive(Debug, Clone, Copy)]
pub struct Format {
    /// Value of the `format` header key.
    pub name: &'static str,
    /// The version written now (sealed).
    pub current: u32,
    /// The last version before seals, still read unverified.
    pub unsealed: u32,
}

/// A file of an Ess format, parsed once, its header and seal checked by [`open`].
pub struct Opened<'a> {
    /// The tensors.
    pub tensors: SafeTensors<'a>,
    /// The header's metadata entries (`format`, `format_version`, the seal, the rest).
    pub header: HashMap<String, String>,
    /// The file's `format_version`.
    pub version: u32,
    /// Whether the seal was verified or the version predates seals.
    pub seal: Seal,
}

impl Opened<'_> {
    /// The header entry `key`, or [`OpenError::MissingKey`].
    pub fn get(&self, key: &'static str) -> Result<&str, OpenError> {
        header_get(&self.header, key)
    }
}

fn header_get<'h>(
    header: &'h HashMap<String, String>,
    key: &'static str,
) -> Result<&'h str, OpenError> {
    header
        .get(key)
        .map(String::as_str)
        .ok_or(OpenError::MissingKey(key))
}

/// Why [`open`] refused a file: its layout, header or seal.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum OpenError {
    /// Not parseable as safetensors at all.
    #[error("not a safetensors file (truncated or corrupt): {0}")]
    Layout(String),
    /// A header entry the format requires is missing.
    #[error("header key {0:?} is missing")]
    MissingKey(&'static str),
    /// The file is of another format.
    #[error("header format = {found:?}, expected {expected:?}")]
    WrongFormat {
        /// The `format` the file names.
        found: String,
        /// The format asked for.
        expected: &'static str,
    },
    /// A `format_version` this build does not read.
    #[error(
        "unsupported format_version {found:?}; this build reads versions {unsealed} and {current}"
    )]
    UnsupportedVersion {
        /// The version the file names.
        found: String,
        /// The version before seals.
        unsealed: u32,
        /// The version written now.
        current: u32,
    },
    /// The content does not match the seal.
    #[error(transparent)]
    Checksum(#[from] ChecksumError),
}

/// Parses `bytes` once and checks, in order, the layout, the `format` and
/// `format_version` header entries against `format`, and the seal (a file of the
/// unsealed version loads unverified): the one sequence every loader of Ess's own
/// formats runs before reading its fields.
pub fn open<'a>(bytes: &'a [u8], format: Format) -> Result<Opened<'a>, OpenError> {
    let layout = |e: safetensors::SafeTensorError| OpenError::Layout(e.to_string());
    let tensors = SafeTensors::deserialize(bytes).map_err(layout)?;
    let (_, md) = SafeTensors::read_metadata(bytes).map_err(layout)?;
    let header = md.metadata().clone().unwrap_or_default();
    let found = header_get(&header, "format")?;
    if found != format.name {
        return Err(OpenError::WrongFormat {
            found: found.to_string(),
            expected: format.name,
        });
    }
    let raw = header_get(&header, "format_version")?;
    let version = match raw.trim().parse::<u32>() {
        Ok(v) if v == format.current || v == format.unsealed => v,
        _ => {
            return Err(OpenError::UnsupportedVersion {
                found: raw.to_string(),
                unsealed: format.unsealed,
                current: format.current,
            });
        }
    };
    let seal = verify_parsed(&tensors, &header, version == format.unsealed)?;
    Ok(Opened {
        tensors,
        header,
        version,
        seal,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(extra: &[(&str, &str)]) -> Vec<u8> {
        let a: Vec<u8> = (0..64u8).collect();
        let b: Vec<u8> = 7.5f64.to_le_bytes().to_vec();
        let views = [
            ("a", TensorView::new(Dtype::F32, vec![4, 4], &a).unwrap()),
            ("b", TensorView::new(Dtype::F64, vec![1], &b).unwrap()),
        ];
        let mut md: HashMap<String, String> = extra
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect();
        seal(&mut md, views.iter().map(|(n, v)| (*n, v)));
        safetensors::serialize(views.iter().map(|(n, v)| (*n, v.clone())), Some(md)).unwrap()
    }

    #[test]
    fn a_sealed_file_verifies_and_every_flipped_byte_is_refused() {
        let bytes = file(&[("meta", "{\"episodes\": 12}")]);
        assert_eq!(verify(&bytes, false), Ok(Seal::Verified));
        for i in 0..bytes.len() {
            for bit in [0, 3, 7] {
                let mut bad = bytes.clone();
                bad[i] ^= 1 << bit;
                assert!(
                    verify(&bad, false).is_err(),
                    "byte {i} bit {bit} flipped was accepted"
                );
            }
        }
    }

    #[test]
    fn the_error_names_the_tensor_or_the_metadata() {
        let bytes = file(&[("meta", "{\"episodes\": 12}")]);
        let mut bad = bytes.clone();
        let n = bad.len();
        bad[n - 1] ^= 1; // last byte of `a` (safetensors puts the 8-byte dtype first)
        assert_eq!(verify(&bad, false), Err(ChecksumError::Tensor("a".into())));
        let text = String::from_utf8_lossy(&bytes).into_owned();
        let at = text.find("12}").unwrap();
        let mut bad = bytes.clone();
        bad[at] = b'9';
        assert_eq!(verify(&bad, false), Err(ChecksumError::Metadata));
    }

    #[test]
    fn an_unsealed_file_is_reported_as_such() {
        let a = [0u8; 4];
        let v = TensorView::new(Dtype::F32, vec![1], &a).unwrap();
        let bytes = safetensors::serialize([("a", v)], None).unwrap();
        assert_eq!(verify(&bytes, true), Ok(Seal::Absent));
        assert_eq!(verify(&bytes, false), Err(ChecksumError::Missing));
    }

    const F: Format = Format {
        name: "ess-test",
        current: 2,
        unsealed: 1,
    };

    fn unsealed(header: &[(&str, &str)]) -> Vec<u8> {
        let a = [0u8; 4];
        let v = TensorView::new(Dtype::F32, vec![1], &a).unwrap();
        let md = header.iter().map(|(k, v)| (k.to_string(), v.to_string()));
        safetensors::serialize([("a", v)], Some(md.collect())).unwrap()
    }

    #[test]
    fn open_checks_format_version_and_seal_in_that_order() {
        let ok = file(&[
            ("format", "ess-test"),
            ("format_version", "2"),
            ("meta", "m"),
        ]);
        let opened = open(&ok, F).unwrap();
        assert_eq!((opened.version, opened.seal), (2, Seal::Verified));
        assert_eq!(opened.get("meta"), Ok("m"));
        assert_eq!(
            opened.get("nope").err(),
            Some(OpenError::MissingKey("nope"))
        );
        let old = unsealed(&[("format", "ess-test"), ("format_version", "1")]);
        assert_eq!(open(&old, F).map(|o| o.seal).ok(), Some(Seal::Absent));
        let err = |bytes: &[u8]| open(bytes, F).err().map(|e| e.to_string());
        let unsealed_v2 = unsealed(&[("format", "ess-test"), ("format_version", "2")]);
        assert_eq!(err(&unsealed_v2), Some(ChecksumError::Missing.to_string()));
        let other = file(&[("format", "ess-other"), ("format_version", "2")]);
        assert_eq!(
            err(&other).as_deref(),
            Some(r#"header format = "ess-other", expected "ess-test""#)
        );
        let v3 = file(&[("format", "ess-test"), ("format_version", "3")]);
        assert_eq!(
            err(&v3).as_deref(),
            Some(r#"unsupported format_version "3"; this build reads versions 1 and 2"#)
        );
        let no_version = file(&[("format", "ess-test")]);
        assert_eq!(
            err(&no_version).as_deref(),
            Some(r#"header key "format_version" is missing"#)
        );
        assert!(err(b"junk").unwrap().starts_with("not a safetensors file"));
    }
}
