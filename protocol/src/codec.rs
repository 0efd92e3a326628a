//! Postcard encodings of the messages, as the MCAP recorder stores them.
//!
//! A record is `version: u16 (varint)` followed by the message. Slice messages (scan and
//! deviation chunks) are the header followed by the sequence of elements.

use serde::Serialize;
use serde::de::DeserializeOwned;

pub use crate::message::{DecodeError, Message};
use crate::{
    ChunkHeader, DeviationHeader, PointDeviation, ProfileHeader, ProfilePoint, ScanPoint,
    check_version,
};

/// One record: the version, then the message.
pub fn encode<M: Message>(msg: &M) -> Vec<u8> {
    let mut out = postcard::to_allocvec(&M::VERSION).expect("u16 always encodes");
    out.extend(postcard::to_allocvec(msg).expect("fixed-size message always encodes"));
    out
}

/// A record back into its message, checking its version and that nothing is left over.
pub fn decode<M: Message>(bytes: &[u8]) -> Result<M, DecodeError> {
    let body = read_version::<M>(bytes)?;
    let (msg, rest): (M, _) = postcard::take_from_bytes(body).map_err(|e| corrupt::<M>(e))?;
    if !rest.is_empty() {
        return Err(DecodeError::TrailingBytes {
            message: M::TYPE_NAME,
            extra: rest.len(),
        });
    }
    check_version::<M>(msg.version())?;
    Ok(msg)
}

/// A record of `M`, or of an older version up to `newest_older` whose layout is `Old`, read
/// into `M`'s layout.
pub(crate) fn decode_or_older<M: Message, Old: DeserializeOwned + Into<M>>(
    bytes: &[u8],
    newest_older: u16,
) -> Result<M, DecodeError> {
    let (version, body): (u16, _) =
        postcard::take_from_bytes(bytes).map_err(|e| corrupt::<M>(e))?;
    if !(1..=newest_older).contains(&version) {
        return decode(bytes);
    }
    let (old, rest): (Old, _) = postcard::take_from_bytes(body).map_err(|e| corrupt::<M>(e))?;
    if !rest.is_empty() {
        return Err(DecodeError::TrailingBytes {
            message: M::TYPE_NAME,
            extra: rest.len(),
        });
    }
    Ok(old.into())
}

/// The leading version of a scan chunk record whose points are byte planes
/// ([`crate::scan_planes`]). Records led by 1 or 2 (the header's own versions) hold the points
/// as a postcard sequence, as releases before this layout wrote them, and still read. The
/// header inside carries its own version, so a later header version needs the next number
/// here, not this one.
pub const SCAN_CHUNK_PLANES: u16 = 3;

/// A scan chunk's record: [`SCAN_CHUNK_PLANES`], the header, then its points as byte planes.
pub fn encode_scan_chunk(header: &ChunkHeader, points: &[ScanPoint]) -> Vec<u8> {
    let mut out = postcard::to_allocvec(&SCAN_CHUNK_PLANES).expect("u16 always encodes");
    out.extend(postcard::to_allocvec(header).expect("fixed-size header always encodes"));
    out.reserve_exact(points.len() * crate::scan_planes::POINT_BYTES);
    crate::scan_planes::encode(points, &mut out);
    out
}

/// A scan chunk's record, in either layout, back into its header and points; the header's
/// `point_count` must match the points that follow.
pub fn decode_scan_chunk(bytes: &[u8]) -> Result<(ChunkHeader, Vec<ScanPoint>), DecodeError> {
    let (layout, body): (u16, _) =
        postcard::take_from_bytes(bytes).map_err(corrupt::<ChunkHeader>)?;
    if layout != SCAN_CHUNK_PLANES {
        return decode_slice(bytes, |h: &ChunkHeader| h.point_count);
    }
    let (header, planes): (ChunkHeader, _) =
        postcard::take_from_bytes(body).map_err(corrupt::<ChunkHeader>)?;
    check_version::<ChunkHeader>(header.version)?;
    let n = header.point_count as usize;
    let want = n.saturating_mul(crate::scan_planes::POINT_BYTES);
    if planes.len() < want {
        return Err(DecodeError::Corrupt {
            message: ChunkHeader::TYPE_NAME,
            reason: format!(
                "header declares {n} points but {} follow ({} bytes)",
                planes.len() / crate::scan_planes::POINT_BYTES,
                planes.len()
            ),
        });
    }
    if planes.len() > want {
        return Err(DecodeError::TrailingBytes {
            message: ChunkHeader::TYPE_NAME,
            extra: planes.len() - want,
        });
    }
    Ok((header, crate::scan_planes::decode(planes, n)))
}

/// A deviation chunk's record: the header, then one deviation per point.
pub fn encode_deviation_chunk(header: &DeviationHeader, points: &[PointDeviation]) -> Vec<u8> {
    encode_slice(header, points)
}

/// A deviation chunk's record back into its header and deviations; the header's
/// `point_count` must match the deviations that follow.
pub fn decode_deviation_chunk(
    bytes: &[u8],
) -> Result<(DeviationHeader, Vec<PointDeviation>), DecodeError> {
    decode_slice(bytes, |h: &DeviationHeader| h.point_count)
}

/// A profile chunk's record: the header, then its points as a postcard sequence.
pub fn encode_profile_chunk(header: &ProfileHeader, points: &[ProfilePoint]) -> Vec<u8> {
    encode_slice(header, points)
}

/// A profile chunk's record back into its header and points; the header's `point_count` must
/// match the points that follow.
pub fn decode_profile_chunk(
    bytes: &[u8],
) -> Result<(ProfileHeader, Vec<ProfilePoint>), DecodeError> {
    decode_slice(bytes, |h: &ProfileHeader| h.point_count)
}

fn encode_slice<H: Message, T: Serialize>(header: &H, items: &[T]) -> Vec<u8> {
    let mut out = encode(header);
    out.extend(postcard::to_allocvec(items).expect("slice of fixed-size items always encodes"));
    out
}

fn decode_slice<H: Message, T: DeserializeOwned>(
    bytes: &[u8],
    declared: impl Fn(&H) -> u32,
) -> Result<(H, Vec<T>), DecodeError> {
    let body = read_version::<H>(bytes)?;
    let (header, rest): (H, _) = postcard::take_from_bytes(body).map_err(|e| corrupt::<H>(e))?;
    check_version::<H>(header.version())?;
    let (items, rest): (Vec<T>, _) =
        postcard::take_from_bytes(rest).map_err(|e| corrupt::<H>(e))?;
    if !rest.is_empty() {
        return Err(DecodeError::TrailingBytes {
            message: H::TYPE_NAME,
            extra: rest.len(),
        });
    }
    if items.len() != declared(&header) as usize {
        return Err(DecodeError::Corrupt {
            message: H::TYPE_NAME,
            reason: format!(
                "header declares {} points but {} follow",
                declared(&header),
                items.len()
            ),
        });
    }
    Ok((header, items))
}

fn read_version<M: Message>(bytes: &[u8]) -> Result<&[u8], DecodeError> {
    let (version, body): (u16, _) =
        postcard::take_from_bytes(bytes).map_err(|e| corrupt::<M>(e))?;
    check_version::<M>(version)?;
    Ok(body)
}

fn corrupt<M: Message>(e: postcard::Error) -> DecodeError {
    DecodeError::Corrupt {
        message: M::TYPE_NAME,
        reason: e.to_string(),
    }
}
