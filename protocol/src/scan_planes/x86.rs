//! [`super::encode`] with SSSE3 and SSE4.1 byte shuffles: sixteen points at a time, one word of
//! each, into sixteen bytes of each of that word's four planes.
//!
//! A scan chunk's record of 65,536 points (`codec::encode_scan_chunk`) took 1.5–1.95 ns a point
//! instead of 2.6–2.7 with the portable loop alone (a timing loop, five rounds each). The
//! `byteshuffle` crate's shuffle of 20-byte elements took 8.2 ns a point on the same points.
//! Like the portable loop, this goes word by word over blocks of points: a chunk's planes lie a
//! multiple of 4 KiB apart when its length is one, and stores to all twenty planes at once fall
//! into the same few cache sets and evict each other (a version doing so took 3.8 ns).

use std::arch::x86_64::*;

use super::{BLOCK, POINT_BYTES, words};
use crate::ScanPoint;

/// Whether this CPU has the shuffles [`encode`] is compiled for. (The check is cached by the
/// standard library.)
pub(super) fn available() -> bool {
    std::arch::is_x86_feature_detected!("ssse3") && std::arch::is_x86_feature_detected!("sse4.1")
}

/// Writes the planes of `points` into `planes` (`points.len() * POINT_BYTES` bytes): the
/// leading multiple of sixteen points here, the rest left for the caller.
/// Returns how many points were written.
///
/// # Safety
/// The CPU must have SSSE3 and SSE4.1 ([`available`]).
#[target_feature(enable = "ssse3,sse4.1")]
pub(super) unsafe fn encode(points: &[ScanPoint], planes: &mut [u8]) -> usize {
    let n = points.len();
    assert_eq!(planes.len(), n * POINT_BYTES);
    let groups = n / 16;
    for first in (0..groups).step_by(BLOCK / 16) {
        let block = first..(first + BLOCK / 16).min(groups);
        word_planes::<0>(points, block.clone(), planes);
        word_planes::<1>(points, block.clone(), planes);
        word_planes::<2>(points, block.clone(), planes);
        word_planes::<3>(points, block.clone(), planes);
        word_planes::<4>(points, block, planes);
    }
    16 * groups
}

/// The four planes of word `W` for the points of `groups` (of sixteen points each). The word is
/// a constant so that only it is taken from each point.
#[target_feature(enable = "ssse3,sse4.1")]
#[inline]
fn word_planes<const W: usize>(
    points: &[ScanPoint],
    groups: std::ops::Range<usize>,
    planes: &mut [u8],
) {
    let n = points.len();
    // The four bytes of one word of four points, as they come in a register (point by point),
    // regrouped byte by byte: byte j of point i goes to 4j + i.
    let by_byte = _mm_setr_epi8(0, 4, 8, 12, 1, 5, 9, 13, 2, 6, 10, 14, 3, 7, 11, 15);
    for g in groups {
        let p: &[ScanPoint; 16] = points[16 * g..16 * g + 16].try_into().expect("sixteen");
        // q[k]: byte j of word W of points 4k..4k+4 in lane j.
        let q: [__m128i; 4] = std::array::from_fn(|k| {
            let word = |i: usize| words(&p[4 * k + i])[W] as i32;
            _mm_shuffle_epi8(_mm_setr_epi32(word(0), word(1), word(2), word(3)), by_byte)
        });
        // Lane j of every q[k] side by side: byte j of the sixteen points.
        let lo = (
            _mm_unpacklo_epi32(q[0], q[1]),
            _mm_unpacklo_epi32(q[2], q[3]),
        );
        let hi = (
            _mm_unpackhi_epi32(q[0], q[1]),
            _mm_unpackhi_epi32(q[2], q[3]),
        );
        let rows = [
            _mm_unpacklo_epi64(lo.0, lo.1),
            _mm_unpackhi_epi64(lo.0, lo.1),
            _mm_unpacklo_epi64(hi.0, hi.1),
            _mm_unpackhi_epi64(hi.0, hi.1),
        ];
        for (j, row) in rows.into_iter().enumerate() {
            let at = (4 * W + j) * n + 16 * g;
            let out = &mut planes[at..at + 16];
            // SAFETY: `out` is sixteen bytes; the store has no alignment need.
            unsafe { _mm_storeu_si128(out.as_mut_ptr().cast(), row) };
        }
    }
}
