//! The one range check every configuration type uses, and the serde test for a value left at zero.

/// A setting outside its valid range: the key and the valid range. Each crate's error type
/// converts it into its own `InvalidConfig` variant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("invalid setting `{field}`: {reason}")]
pub struct OutOfRange {
    /// Name of the field.
    pub field: &'static str,
    /// What the valid range is.
    pub reason: &'static str,
}

/// `Ok` when `ok`, otherwise the [`OutOfRange`] naming `field` and its valid range `reason`.
pub fn check_setting(
    ok: bool,
    field: &'static str,
    reason: &'static str,
) -> Result<(), OutOfRange> {
    if ok {
        Ok(())
    } else {
        Err(OutOfRange { field, reason })
    }
}

/// `skip_serializing_if` for a value whose zero means "not set", so stored configurations and
/// records keep their form when it is.
pub fn is_zero(v: &f32) -> bool {
    *v == 0.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_failed_check_names_the_field_and_its_range() {
        assert_eq!(check_setting(true, "a", "b"), Ok(()));
        let e = check_setting(false, "top_k", "must be ≥ 1").unwrap_err();
        assert_eq!((e.field, e.reason), ("top_k", "must be ≥ 1"));
        assert_eq!(e.to_string(), "invalid setting `top_k`: must be ≥ 1");
    }
}
