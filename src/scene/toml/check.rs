//! Checks of one value each, returning `file: field: problem`.
use clap::ValueEnum;
use glam::Vec3;
use std::path::Path;

use crate::error::{Error, Result};

/// Checks of one value, each returning the field's error.
pub(super) struct Check<'a> {
    pub(super) path: &'a Path,
}

impl Check<'_> {
    pub(super) fn err(&self, field: &str, msg: String) -> Error {
        Error::field(self.path, field, msg)
    }

    /// One of `T`'s values by its command-line name, or `default` when absent.
    pub(super) fn word<T: ValueEnum>(&self, field: &str, v: Option<&str>, default: T) -> Result<T> {
        let Some(w) = v else { return Ok(default) };
        T::from_str(w, false).map_err(|_| {
            let names: Vec<String> = T::value_variants()
                .iter()
                .filter_map(|v| v.to_possible_value())
                .map(|p| p.get_name().to_string())
                .collect();
            let (last, rest) = names.split_last().expect("an enum has values");
            let list = if rest.is_empty() {
                last.clone()
            } else {
                format!("{} or {last}", rest.join(", "))
            };
            self.err(field, format!("expected {list}, got \"{w}\""))
        })
    }
    pub(super) fn finite3(&self, field: &str, v: [f32; 3]) -> Result<Vec3> {
        if v.iter().all(|x| x.is_finite()) {
            Ok(Vec3::from(v))
        } else {
            Err(self.err(field, format!("expected finite numbers, got {v:?}")))
        }
    }
    pub(super) fn nonneg3(&self, field: &str, v: [f32; 3]) -> Result<Vec3> {
        if v.iter().all(|x| x.is_finite() && *x >= 0.0) {
            Ok(Vec3::from(v))
        } else {
            Err(self.err(field, format!("expected finite numbers >= 0, got {v:?}")))
        }
    }
    pub(super) fn unit3(&self, field: &str, v: [f32; 3]) -> Result<Vec3> {
        let v = self.finite3(field, v)?;
        if v.length_squared() > 0.0 {
            Ok(v.normalize())
        } else {
            Err(self.err(field, "expected a non-zero direction".into()))
        }
    }
    pub(super) fn in_range(
        &self,
        field: &str,
        x: f32,
        lo: f32,
        hi: f32,
        what: &str,
    ) -> Result<f32> {
        if x.is_finite() && x >= lo && x <= hi {
            Ok(x)
        } else {
            Err(self.err(field, format!("expected {what}, got {x}")))
        }
    }
    pub(super) fn positive(&self, field: &str, x: f32) -> Result<f32> {
        if x.is_finite() && x > 0.0 {
            Ok(x)
        } else {
            Err(self.err(field, format!("expected a finite number > 0, got {x}")))
        }
    }
}

/// 1-based line of a byte offset, for parse errors.
pub(super) fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].matches('\n').count() + 1
}
