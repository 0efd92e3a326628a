use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// Bounded UTF-8 text with a fixed in-memory layout, for names inside zero-copy payloads.
///
/// On the wire (postcard) it is a `heapless::String<N>`, so a record can never make a reader
/// allocate more than `N` bytes for it.
#[derive(Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[repr(C)]
pub struct FixedText<const N: usize> {
    len: u32,
    bytes: [u8; N],
}

/// The text does not fit the fixed capacity of its field.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("text of {len} bytes does not fit a field of {capacity} bytes; use a shorter name")]
pub struct TextTooLong {
    /// The text's length in bytes.
    pub len: usize,
    /// The field's capacity in bytes.
    pub capacity: usize,
}

impl<const N: usize> FixedText<N> {
    /// No text.
    pub const fn empty() -> Self {
        Self {
            len: 0,
            bytes: [0; N],
        }
    }

    /// The text, or an error when it is longer than `N` bytes.
    pub fn new(text: &str) -> Result<Self, TextTooLong> {
        if text.len() > N {
            return Err(TextTooLong {
                len: text.len(),
                capacity: N,
            });
        }
        let mut out = Self::empty();
        out.bytes[..text.len()].copy_from_slice(text.as_bytes());
        out.len = text.len() as u32;
        Ok(out)
    }

    /// Cuts at a character boundary instead of failing; for labels that are only shown.
    pub fn truncated(text: &str) -> Self {
        let mut end = text.len().min(N);
        while !text.is_char_boundary(end) {
            end -= 1;
        }
        Self::new(&text[..end]).expect("cut to capacity")
    }

    /// The text.
    pub fn as_str(&self) -> &str {
        // A payload from shared memory is foreign data: never trust its length or its bytes.
        let len = (self.len as usize).min(N);
        match std::str::from_utf8(&self.bytes[..len]) {
            Ok(s) => s,
            Err(e) => std::str::from_utf8(&self.bytes[..e.valid_up_to()]).unwrap_or(""),
        }
    }
}

impl<const N: usize> Default for FixedText<N> {
    fn default() -> Self {
        Self::empty()
    }
}

impl<const N: usize> std::fmt::Debug for FixedText<N> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        std::fmt::Debug::fmt(self.as_str(), f)
    }
}

impl<const N: usize> std::fmt::Display for FixedText<N> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl<const N: usize> Serialize for FixedText<N> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.as_str())
    }
}

impl<'de, const N: usize> Deserialize<'de> for FixedText<N> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let text = heapless::String::<N>::deserialize(d)?;
        Self::new(&text).map_err(serde::de::Error::custom)
    }
}
