//! The instruction set the wide loops run with, chosen once per process at run time, so
//! one portable binary uses AVX2 or AVX-512 on the farm nodes that have them.
//!
//! A wide loop is written once, over fixed-size lanes in plain Rust, and compiled again
//! inside `#[target_feature]` functions, where LLVM turns the lanes into vector registers.
//! It does the scalar code's IEEE operations in the scalar code's order (Rust neither
//! fuses a multiply and an add nor reassociates unless asked), so every instruction set
//! gives the same bits. Hand-written dispatch, not the `multiversion` crate: `PPB_SIMD`
//! must be able to force the scalar reference path, and `--stats` names the path that ran.
use std::sync::OnceLock;

/// An instruction set the wide loops are compiled for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Isa {
    /// One lane at a time: the reference path.
    Scalar,
    /// 8 f32 lanes.
    Avx2,
    /// 16 f32 lanes.
    Avx512,
}

/// The environment variable that asks for an instruction set.
pub const ENV: &str = "PPB_SIMD";

impl Isa {
    pub const ALL: [Isa; 3] = [Isa::Scalar, Isa::Avx2, Isa::Avx512];

    pub fn name(self) -> &'static str {
        match self {
            Isa::Scalar => "scalar",
            Isa::Avx2 => "avx2",
            Isa::Avx512 => "avx512",
        }
    }

    /// Whether this CPU runs it.
    pub fn supported(self) -> bool {
        match self {
            Isa::Scalar => true,
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 => std::arch::is_x86_feature_detected!("avx2"),
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512 => {
                std::arch::is_x86_feature_detected!("avx512f")
                    && std::arch::is_x86_feature_detected!("avx2")
            }
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }

    /// The widest this CPU runs.
    pub fn detected() -> Isa {
        Isa::ALL
            .into_iter()
            .rev()
            .find(|i| i.supported())
            .unwrap_or(Isa::Scalar)
    }

    /// The set `PPB_SIMD` asks for (unset or empty: the widest this CPU runs), or what is
    /// wrong with its value.
    pub fn from_env() -> Result<Isa, String> {
        let value = std::env::var(ENV).unwrap_or_default();
        Isa::choose(&value)
    }

    /// [`Self::from_env`] for a given value.
    pub fn choose(value: &str) -> Result<Isa, String> {
        if value.is_empty() {
            return Ok(Isa::detected());
        }
        let names = || Isa::ALL.map(Isa::name).join(", ");
        let isa = Isa::ALL
            .into_iter()
            .find(|i| i.name() == value)
            .ok_or_else(|| format!("{ENV}={value}: expected one of {}", names()))?;
        if !isa.supported() {
            return Err(format!(
                "{ENV}={value}: this CPU does not run it (it runs up to {})",
                Isa::detected().name()
            ));
        }
        Ok(isa)
    }
}

/// The instruction set of this process: `PPB_SIMD`'s, or the widest the CPU runs when the
/// variable is unset or wrong (the binary reports a wrong value before it renders).
pub fn isa() -> Isa {
    static ISA: OnceLock<Isa> = OnceLock::new();
    *ISA.get_or_init(|| Isa::from_env().unwrap_or_else(|_| Isa::detected()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn choose_names_the_variable_and_the_choices() {
        assert_eq!(Isa::choose("scalar"), Ok(Isa::Scalar));
        assert_eq!(Isa::choose(""), Ok(Isa::detected()));
        let err = Isa::choose("neon").unwrap_err();
        assert!(
            err.contains("PPB_SIMD=neon") && err.contains("scalar, avx2, avx512"),
            "{err}"
        );
        for isa in Isa::ALL {
            assert_eq!(Isa::choose(isa.name()).is_ok(), isa.supported(), "{isa:?}");
        }
    }
}
