//! Deterministic mutations of a valid file: what a bad disk, a cut transfer, a buggy exporter or
//! a hostile peer makes of it.

use rand::{Rng, RngCore};

/// Numbers that break parsers and arithmetic: zero, signs, limits, NaN, infinities, and counts
/// that claim more than any file holds.
const EXTREME_U64: [u64; 10] = [
    0,
    1,
    0x7f,
    0xff,
    0xffff,
    0x7fff_ffff,
    0xffff_ffff,
    0x7fff_ffff_ffff_ffff,
    u64::MAX,
    1 << 40,
];
const EXTREME_F64: [f64; 8] = [
    f64::NAN,
    f64::INFINITY,
    f64::NEG_INFINITY,
    f64::MAX,
    f64::MIN_POSITIVE,
    -0.0,
    1e300,
    1e-300,
];
const EXTREME_TEXT: [&str; 12] = [
    "nan",
    "inf",
    "-inf",
    "1e308",
    "-1e308",
    "1e-320",
    "99999999999999999999999",
    "-1",
    "0",
    "4294967296",
    "",
    "\u{feff}",
];

/// One to four mutations of `seed`. `text` adds mutations of number tokens, for text formats.
pub fn mutate(seed: &[u8], rng: &mut impl RngCore, text: bool) -> Vec<u8> {
    let mut b = seed.to_vec();
    let n = rng.random_range(1..=4);
    for _ in 0..n {
        let kinds = if text { 8 } else { 7 };
        match rng.random_range(0..kinds) {
            0 => flip_bits(&mut b, rng),
            1 => cut(&mut b, rng),
            2 => insert(&mut b, rng),
            3 => extreme_binary(&mut b, rng),
            4 => copy_range(&mut b, rng),
            5 => swap_ranges(&mut b, rng),
            6 => set_bytes(&mut b, rng),
            _ => extreme_token(&mut b, rng),
        }
    }
    b
}

fn pos(b: &[u8], rng: &mut impl RngCore) -> usize {
    if b.is_empty() {
        0
    } else {
        rng.random_range(0..b.len())
    }
}

fn flip_bits(b: &mut [u8], rng: &mut impl RngCore) {
    if b.is_empty() {
        return;
    }
    for _ in 0..rng.random_range(1..=8) {
        let i = pos(b, rng);
        b[i] ^= 1 << rng.random_range(0..8);
    }
}

/// The file cut short (a transfer or a writer that died), or its head cut off.
fn cut(b: &mut Vec<u8>, rng: &mut impl RngCore) {
    let at = pos(b, rng);
    if rng.random_bool(0.8) {
        b.truncate(at);
    } else {
        b.drain(..at);
    }
}

fn insert(b: &mut Vec<u8>, rng: &mut impl RngCore) {
    let at = pos(b, rng);
    let len = rng.random_range(1..=64);
    let bytes: Vec<u8> = (0..len).map(|_| rng.random()).collect();
    b.splice(at..at, bytes);
}

/// An integer or float field overwritten with a limit, at any alignment.
fn extreme_binary(b: &mut [u8], rng: &mut impl RngCore) {
    let bytes: Vec<u8> = match rng.random_range(0..4) {
        0 => (EXTREME_U64[rng.random_range(0..EXTREME_U64.len())] as u32)
            .to_le_bytes()
            .to_vec(),
        1 => EXTREME_U64[rng.random_range(0..EXTREME_U64.len())]
            .to_le_bytes()
            .to_vec(),
        2 => (EXTREME_F64[rng.random_range(0..EXTREME_F64.len())] as f32)
            .to_le_bytes()
            .to_vec(),
        _ => EXTREME_F64[rng.random_range(0..EXTREME_F64.len())]
            .to_le_bytes()
            .to_vec(),
    };
    if b.len() < bytes.len() {
        return;
    }
    let at = rng.random_range(0..=b.len() - bytes.len());
    b[at..at + bytes.len()].copy_from_slice(&bytes);
}

/// A stretch of the file written again elsewhere (a duplicated record or chunk).
fn copy_range(b: &mut Vec<u8>, rng: &mut impl RngCore) {
    if b.len() < 2 {
        return;
    }
    let from = pos(b, rng);
    let len = rng.random_range(1..=(b.len() - from).min(4096));
    let piece = b[from..from + len].to_vec();
    let at = pos(b, rng);
    b.splice(at..at, piece);
}

/// Two stretches of equal length exchanged (records out of order).
fn swap_ranges(b: &mut [u8], rng: &mut impl RngCore) {
    if b.len() < 4 {
        return;
    }
    let len = rng.random_range(1..=(b.len() / 2).min(4096));
    let x = rng.random_range(0..=b.len() - 2 * len);
    let y = rng.random_range(x + len..=b.len() - len);
    let (head, tail) = b.split_at_mut(y);
    head[x..x + len].swap_with_slice(&mut tail[..len]);
}

fn set_bytes(b: &mut [u8], rng: &mut impl RngCore) {
    if b.is_empty() {
        return;
    }
    let at = pos(b, rng);
    let len = rng.random_range(1..=16).min(b.len() - at);
    let v = [0u8, 0xff, 0x7f, 0x80, b' ', b'\n', b'-', b'9'][rng.random_range(0..8)];
    b[at..at + len].fill(v);
}

/// A number in a text file replaced by a value that breaks parsers or arithmetic.
fn extreme_token(b: &mut Vec<u8>, rng: &mut impl RngCore) {
    let starts: Vec<usize> = (0..b.len())
        .filter(|&i| b[i].is_ascii_digit() && (i == 0 || !b[i - 1].is_ascii_alphanumeric()))
        .collect();
    if starts.is_empty() {
        return;
    }
    let start = starts[rng.random_range(0..starts.len())];
    let end = (start..b.len())
        .find(|&i| !(b[i].is_ascii_alphanumeric() || matches!(b[i], b'.' | b'-' | b'+')))
        .unwrap_or(b.len());
    let token = EXTREME_TEXT[rng.random_range(0..EXTREME_TEXT.len())].as_bytes();
    b.splice(start..end, token.iter().copied());
}
