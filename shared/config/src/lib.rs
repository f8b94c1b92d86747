//! Pipeline configuration: TOML loading and validation
