//! A scan chunk's points as byte planes, the layout of a v3 scan chunk record.
//!
//! A point is five little-endian 32-bit words: x, y, z, intensity (f32 bits), then flags (u16)
//! with returns and the reserved byte. Plane `4w + j` holds byte `j` of word `w` of every point,
//! in order. Neighbouring points share their floats' sign, exponent and high mantissa bytes, so
//! those planes are long runs that the chunk compressor takes almost for free, while only the
//! noisy low bytes cost. On the demo's chunks, this layout at zstd level 1 keeps 8.6 bytes of a
//! point's 20 in 33 ns (laying out and compressing), where postcard's 19 at level 3 kept 12.8
//! in 168 ns (the README's "Recordings"); the recorder now trades a few per cent of that for a
//! faster zstd level (`recording::ZSTD_LEVEL`). The layout is lossless: every bit comes back.

use crate::{ScanPoint, ScanPointFlags};

/// Bytes of one point in the planes.
pub const POINT_BYTES: usize = 20;

/// The five words of a point, in plane order.
fn words(p: &ScanPoint) -> [u32; 5] {
    let [lo, hi] = p.flags.0.to_le_bytes();
    [
        p.xyz[0].to_bits(),
        p.xyz[1].to_bits(),
        p.xyz[2].to_bits(),
        p.intensity.to_bits(),
        u32::from_le_bytes([lo, hi, p.returns, p._reserved]),
    ]
}

#[cfg(target_arch = "x86_64")]
mod x86;

/// Points per pass: each pass writes four planes over a block small enough to stay in the
/// first-level cache for the five passes.
const BLOCK: usize = 1024;

/// Appends `points` to `out` as 20 planes of `points.len()` bytes each.
pub fn encode(points: &[ScanPoint], out: &mut Vec<u8>) {
    let n = points.len();
    let start = out.len();
    out.resize(start + n * POINT_BYTES, 0);
    let planes = &mut out[start..];
    #[cfg(target_arch = "x86_64")]
    if x86::available() {
        // SAFETY: the CPU has the instructions `x86::encode` is compiled for.
        let done = unsafe { x86::encode(points, planes) };
        encode_from(points, done, planes);
        return;
    }
    encode_from(points, 0, planes);
}

/// The planes of `points[from..]`, in `planes` laid out for all of `points`: the portable
/// loop, word by word over blocks of points, each pass writing four planes in step.
fn encode_from(points: &[ScanPoint], from: usize, planes: &mut [u8]) {
    let n = points.len();
    for (b, block) in points[from..].chunks(BLOCK).enumerate() {
        let at = from + b * BLOCK;
        let end = at + block.len();
        for (w, planes) in planes.chunks_exact_mut(4 * n).enumerate() {
            let (b0, rest) = planes.split_at_mut(n);
            let (b1, rest) = rest.split_at_mut(n);
            let (b2, b3) = rest.split_at_mut(n);
            let lanes = b0[at..end].iter_mut().zip(&mut b1[at..end]);
            let lanes = lanes.zip(&mut b2[at..end]).zip(&mut b3[at..end]);
            for ((((x0, x1), x2), x3), p) in lanes.zip(block) {
                [*x0, *x1, *x2, *x3] = words(p)[w].to_le_bytes();
            }
        }
    }
}

/// The `n` points whose planes are `bytes`, which must be exactly `n * POINT_BYTES` long
/// (the caller checks, so nothing is allocated that the input does not hold).
pub fn decode(bytes: &[u8], n: usize) -> Vec<ScanPoint> {
    debug_assert_eq!(bytes.len(), n * POINT_BYTES);
    let mut points = vec![ScanPoint::default(); n];
    if n == 0 {
        return points;
    }
    for (w, planes) in bytes.chunks_exact(4 * n).enumerate() {
        let (b0, rest) = planes.split_at(n);
        let (b1, rest) = rest.split_at(n);
        let (b2, b3) = rest.split_at(n);
        let word = (b0.iter().zip(b1).zip(b2).zip(b3))
            .map(|(((&a, &b), &c), &d)| [a, b, c, d])
            .zip(points.iter_mut());
        match w {
            0..=2 => word.for_each(|(b, p)| p.xyz[w] = f32::from_le_bytes(b)),
            3 => word.for_each(|(b, p)| p.intensity = f32::from_le_bytes(b)),
            _ => word.for_each(|([lo, hi, returns, reserved], p)| {
                p.flags = ScanPointFlags(u16::from_le_bytes([lo, hi]));
                p.returns = returns;
                p._reserved = reserved;
            }),
        }
    }
    points
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The planes as the layout defines them, one byte at a time: what [`encode`] must equal.
    fn encode_bytewise(points: &[ScanPoint]) -> Vec<u8> {
        let n = points.len();
        let mut out = vec![0; n * POINT_BYTES];
        for (i, p) in points.iter().enumerate() {
            for (w, word) in words(p).into_iter().enumerate() {
                for (j, byte) in word.to_le_bytes().into_iter().enumerate() {
                    out[(4 * w + j) * n + i] = byte;
                }
            }
        }
        out
    }

    /// Every bit of every field comes back, NaNs and signed zeros included, and the planes are
    /// where the layout says.
    #[test]
    fn planes_keep_every_bit() {
        let points: Vec<ScanPoint> = (0..1000u32)
            .map(|i| ScanPoint {
                xyz: [
                    f32::from_bits(i.wrapping_mul(2_654_435_761)),
                    -0.0,
                    f32::from_bits(0x7fc0_0001 + i),
                ],
                intensity: i as f32 * 0.25,
                flags: ScanPointFlags(i as u16 * 3),
                returns: (i % 251) as u8,
                _reserved: (i % 7) as u8,
            })
            .collect();
        let mut bytes = vec![0xAB];
        encode(&points, &mut bytes);
        assert_eq!(bytes.len(), 1 + points.len() * POINT_BYTES);
        let back = decode(&bytes[1..], points.len());
        for (a, b) in points.iter().zip(&back) {
            assert_eq!(words(a), words(b));
        }
        // Byte 3 of word 1 (y = -0.0: 0x8000_0000) of point 5 sits in plane 7.
        let n = points.len();
        assert_eq!(bytes[1 + 7 * n + 5], 0x80);
        assert_eq!(bytes[1 + 16 * n + 5], 15, "flags' low byte of point 5");
        assert!(decode(&[], 0).is_empty());
        let mut none = Vec::new();
        encode(&[], &mut none);
        assert!(none.is_empty());
    }

    /// The blocked layout gives the bytes of the definition, for chunks shorter than a block,
    /// a block exactly, and a ragged last block; so do the portable loop alone and the shuffles
    /// (for the points they take: whole groups of sixteen).
    #[test]
    fn planes_are_the_bytes_of_their_definition() {
        for n in [1, 7, 15, 16, 17, 1023, 1024, 1025, 1040, 3000, 4096] {
            let points: Vec<ScanPoint> = (0..n as u32)
                .map(|i| ScanPoint {
                    xyz: [
                        f32::from_bits(i.wrapping_mul(2_654_435_761)),
                        f32::from_bits(i.wrapping_mul(40_503) ^ 0x5555_aaaa),
                        i as f32 * -0.001,
                    ],
                    intensity: f32::from_bits(!i),
                    flags: ScanPointFlags(i as u16 ^ 0xbeef),
                    returns: (i * 13) as u8,
                    _reserved: (i * 29) as u8,
                })
                .collect();
            let want = encode_bytewise(&points);
            let mut planes = vec![0x11, 0x22];
            encode(&points, &mut planes);
            assert_eq!(planes[..2], [0x11, 0x22], "what was in the buffer stays");
            assert_eq!(planes[2..], want, "{n} points");
            // The portable loop alone, as a CPU without the shuffles runs it.
            let mut portable = vec![0; want.len()];
            encode_from(&points, 0, &mut portable);
            assert_eq!(portable, want, "{n} points, portable");
            #[cfg(target_arch = "x86_64")]
            if x86::available() {
                let mut shuffled = vec![0; want.len()];
                // SAFETY: checked just above.
                let done = unsafe { x86::encode(&points, &mut shuffled) };
                assert_eq!(done, n / 16 * 16);
                let split = |planes: &[u8]| -> Vec<Vec<u8>> {
                    planes
                        .chunks(n)
                        .map(|plane| plane[..done].to_vec())
                        .collect()
                };
                assert_eq!(split(&shuffled), split(&want), "{n} points, shuffles");
            }
        }
    }
}
