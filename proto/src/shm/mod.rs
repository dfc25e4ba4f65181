//! `#[repr(C)]` layouts of what travels through shared memory between actor processes
//! and the learner: transition chunks (actor -> learner) and policy weights with p(c)
//! (learner -> actors).
//!
//! Both are one flat, 8-byte aligned byte buffer (an iceoryx2 sample with a `[u64]` slice
//! payload): a fixed header, then the arrays back to back, each at an offset computed
//! from the header's counts and dims. Nothing is serialised:
//!
//! - the actor writes every step straight into the loaned sample through
//!   [`ShmChunkWriter`] (a [`StepSink`], like [`Chunk`] itself), so the rollout loop is
//!   the only writer and there is no copy before publishing;
//! - the learner reads a received sample with [`read_chunk`], which copies the arrays
//!   once into an owned [`Chunk`] (the learner keeps chunks across the iteration and
//!   hands them to tch, so one copy on this side is accepted);
//! - weights go the other way with [`write_weights`] / [`read_weights`].
//!
//! Alignment: the buffer start must be 8-byte aligned (a `[u64]` payload is); every `f32`
//! array then starts at a multiple of 4, the `bool` arrays (one byte each, 0 or 1) come
//! last. A buffer that is too short, misaligned, or whose header disagrees with its
//! length is refused with a [`ShmError`] naming what is wrong, never read past its end.

//!
//! Files: [`chunk`] (transitions), [`weights`] (policy weights and p(c)), [`episode`]
//! (deterministic evaluation episodes); this file holds what they share (the error
//! type, the buffer checks).

mod chunk;
mod episode;
mod weights;

pub use chunk::*;
pub use episode::*;
pub use weights::*;

use thiserror::Error;

/// `b"ESSC"`: first field of a chunk header.
pub const CHUNK_MAGIC: u32 = u32::from_le_bytes(*b"ESSC");
/// `b"ESSW"`: first field of a weights header.
pub const WEIGHTS_MAGIC: u32 = u32::from_le_bytes(*b"ESSW");
/// Version of these layouts; bumped on any change.
pub const LAYOUT_VERSION: u32 = 2;
/// Most MLP layer sizes (input, hidden.., output) a weights header can carry.
pub const MAX_LAYER_SIZES: usize = 8;

/// Errors about a shared-memory buffer.
#[derive(Debug, Error, PartialEq, Eq)]
pub enum ShmError {
    /// The buffer is shorter than its header says it must be.
    #[error("{what} buffer holds {got} bytes, needs {needed}")]
    TooShort {
        /// Chunk or weights.
        what: &'static str,
        /// Bytes needed.
        needed: usize,
        /// Bytes present.
        got: usize,
    },
    /// The buffer does not start at an 8-byte boundary.
    #[error("{what} buffer is not 8-byte aligned")]
    Misaligned {
        /// Chunk or weights.
        what: &'static str,
    },
    /// Wrong magic or layout version.
    #[error(
        "{what} header has magic {magic:#x} / layout version {version}, expected {expected_magic:#x} / {LAYOUT_VERSION}"
    )]
    BadHeader {
        /// Chunk or weights.
        what: &'static str,
        /// Magic found.
        magic: u32,
        /// Expected magic.
        expected_magic: u32,
        /// Layout version found.
        version: u32,
    },
    /// A field's value is out of range.
    #[error("{what} field `{field}` = {value}: {reason}")]
    BadField {
        /// Chunk or weights.
        what: &'static str,
        /// Field name.
        field: &'static str,
        /// Its value.
        value: String,
        /// Why it is refused.
        reason: &'static str,
    },
    /// More steps pushed than the buffer was laid out for.
    #[error("chunk buffer is full: laid out for {capacity} steps")]
    Full {
        /// Steps the buffer holds.
        capacity: usize,
    },
}

/// FNV-1a 64 of a run id: stamped into every chunk so a learner never accepts a chunk of
/// another run.
pub fn run_id_hash(run_id: &str) -> u64 {
    run_id.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// The header `H` at the start of `buf`: aligned, long enough, with `expected_magic` and
/// this [`LAYOUT_VERSION`] (`magic_version` reads those two fields).
fn checked_header<H: bytemuck::Pod>(
    buf: &[u8],
    what: &'static str,
    expected_magic: u32,
    magic_version: impl Fn(&H) -> (u32, u32),
) -> Result<H, ShmError> {
    let bytes = std::mem::size_of::<H>();
    check_aligned(buf, what)?;
    check_len(buf, what, bytes)?;
    let h: H =
        *bytemuck::try_from_bytes(&buf[..bytes]).map_err(|_| ShmError::Misaligned { what })?;
    let (magic, version) = magic_version(&h);
    if magic != expected_magic || version != LAYOUT_VERSION {
        return Err(ShmError::BadHeader {
            what,
            magic,
            expected_magic,
            version,
        });
    }
    Ok(h)
}

/// `buf` holds at least `needed` bytes of a `what`.
fn check_len(buf: &[u8], what: &'static str, needed: usize) -> Result<(), ShmError> {
    if buf.len() < needed {
        return Err(ShmError::TooShort {
            what,
            needed,
            got: buf.len(),
        });
    }
    Ok(())
}

fn check_aligned(buf: &[u8], what: &'static str) -> Result<(), ShmError> {
    if !(buf.as_ptr() as usize).is_multiple_of(8) {
        return Err(ShmError::Misaligned { what });
    }
    Ok(())
}

fn split_f32_mut<'a>(rest: &mut &'a mut [u8], n: usize) -> Result<&'a mut [f32], ShmError> {
    let (head, tail) = std::mem::take(rest).split_at_mut(4 * n);
    *rest = tail;
    bytemuck::try_cast_slice_mut(head).map_err(|_| ShmError::Misaligned { what: "chunk" })
}

fn split_f32<'a>(rest: &mut &'a [u8], n: usize) -> Result<&'a [f32], ShmError> {
    let (head, tail) = rest.split_at(4 * n);
    *rest = tail;
    bytemuck::try_cast_slice(head).map_err(|_| ShmError::Misaligned { what: "chunk" })
}

#[cfg(test)]
mod tests;
