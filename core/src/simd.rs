//! Kernels compiled twice: for AVX2, chosen at run time where the CPU has it, and for the
//! build's baseline. The release build targets plain x86-64 so that one binary runs on any edge
//! PC; the hot loops (C2M's triangle lanes, M3C2's cylinder tests) still get 256-bit registers.

/// Whether this CPU has AVX2: the kernels then fill 256-bit registers.
/// (The check is cached by the standard library.)
#[inline]
pub(crate) fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    return std::arch::is_x86_feature_detected!("avx2");
    #[cfg(not(target_arch = "x86_64"))]
    false
}

/// Runs a body compiled for AVX2 where the CPU has it, so that the lanes fill 256-bit
/// registers, and as it is elsewhere; no FMA is enabled, so both give the same bits. The body
/// is a function of the named values (`name: Type = value`), and what it calls with
/// `#[inline(always)]` is compiled into it. A closure would not do: the compiler may leave a
/// large one out of line, and then it runs without AVX2 (it did, in the `asbuilt` binary).
macro_rules! avx2 {
    (
        $(<$($g:ident: $b:path),*>)?
        [$($arg:ident: $ty:ty = $val:expr),* $(,)?] -> $ret:ty $body:block
    ) => {{
        #[inline(always)]
        fn body$(<$($g: $b),*>)?($($arg: $ty),*) -> $ret $body
        #[cfg_attr(target_arch = "x86_64", target_feature(enable = "avx2"))]
        unsafe fn avx2$(<$($g: $b),*>)?($($arg: $ty),*) -> $ret {
            body($($arg),*)
        }
        if $crate::simd::has_avx2() {
            // SAFETY: the CPU has AVX2 (`has_avx2` is false on other architectures).
            unsafe { avx2($($val),*) }
        } else {
            body($($val),*)
        }
    }};
}
pub(crate) use avx2;
