//! The one range check every configuration type uses.

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
