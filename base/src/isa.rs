//! The one choice of CPU instruction set for every fast kernel in the project: the last build
//! the CPU can run, unless `METASPLAT_NO_AVX2` (the portable loops) or `METASPLAT_NO_AVX512`
//! (AVX2 at most) is set, so that tests and benchmarks can run each build on one machine. Every
//! build gives the same bits (no multiply-add is fused unless the portable loop fuses it too),
//! so the choice changes speed only.
//!
//! [`simd_builds!`](crate::simd_builds) compiles a plain loop once per build and dispatches on
//! [`Isa::chosen`]; hand-written intrinsics (`splat::cpu::blend`) match on it themselves.

/// The builds of the kernels, all giving the same bits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Isa {
    /// Plain Rust for every CPU.
    Portable,
    /// AVX2 and FMA.
    Avx2,
    /// AVX-512 (F and VL) on top of AVX2 (32 vector registers).
    Avx512,
}

impl Isa {
    /// The builds this CPU can run, portable first.
    pub fn available() -> Vec<Isa> {
        let mut v = vec![Isa::Portable];
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::is_x86_feature_detected as has;
            if has!("avx2") && has!("fma") && has!("popcnt") {
                v.push(Isa::Avx2);
                if has!("avx512f") && has!("avx512vl") {
                    v.push(Isa::Avx512);
                }
            }
        }
        v
    }

    /// The build every kernel uses (read once per process).
    pub fn chosen() -> Isa {
        static ISA: std::sync::OnceLock<Isa> = std::sync::OnceLock::new();
        *ISA.get_or_init(|| {
            let off = |v| std::env::var_os(v).is_some();
            Isa::available()
                .into_iter()
                .filter(|&i| !(off("METASPLAT_NO_AVX2") && i != Isa::Portable))
                .rfind(|&i| !(off("METASPLAT_NO_AVX512") && i == Isa::Avx512))
                .unwrap_or(Isa::Portable)
        })
    }
}

/// Compiles a function of plain loops once per [`Isa`] (portable, AVX2 + FMA, AVX-512) and
/// calls the build [`Isa::chosen`] names. The arguments must be plain `name: Type` pairs.
#[macro_export]
macro_rules! simd_builds {
    ($(#[$meta:meta])* $vis:vis fn $name:ident($($arg:ident : $ty:ty),* $(,)?) $(-> $ret:ty)? $body:block) => {
        $(#[$meta])*
        $vis fn $name($($arg: $ty),*) $(-> $ret)? {
            #[inline(always)]
            fn body($($arg: $ty),*) $(-> $ret)? $body
            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = "avx2,fma")]
            unsafe fn avx2($($arg: $ty),*) $(-> $ret)? {
                body($($arg),*)
            }
            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = "avx512f,avx512vl,avx2,fma")]
            unsafe fn avx512($($arg: $ty),*) $(-> $ret)? {
                body($($arg),*)
            }
            match $crate::isa::Isa::chosen() {
                // SAFETY: `Isa::chosen` names only a build the CPU has.
                #[cfg(target_arch = "x86_64")]
                $crate::isa::Isa::Avx512 => unsafe { avx512($($arg),*) },
                // SAFETY: as above.
                #[cfg(target_arch = "x86_64")]
                $crate::isa::Isa::Avx2 => unsafe { avx2($($arg),*) },
                _ => body($($arg),*),
            }
        }
    };
}
