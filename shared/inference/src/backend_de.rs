//! Reading a [`BackendConfig`] whose `kind` may be missing: the table is held in a [`Value`]
//! (any self-describing input: TOML, JSON), given the default backend's `kind` if it has none,
//! and then read as the tagged enum. A JSON value would do the holding too, but it cannot hold
//! the non-finite floats TOML can write (`inf`, `nan`), which the range checks must see.
use crate::{AnalyticConfig, BackendConfig, LearnedConfig, VgnConfig};
use serde::de::value::{MapDeserializer, SeqDeserializer};
use serde::de::{self, Deserialize, Deserializer, IntoDeserializer, Visitor};
use std::fmt;

/// The serde shape of [`BackendConfig`] once `kind` is known.
#[derive(serde::Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
enum Tagged {
    Analytic(AnalyticConfig),
    Learned(LearnedConfig),
    Vgn(VgnConfig),
}

impl<'de> Deserialize<'de> for BackendConfig {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let mut value = Value::deserialize(deserializer)?;
        if let Value::Map(entries) = &mut value {
            let has_kind = entries
                .iter()
                .any(|(k, _)| matches!(k, Value::Str(k) if k == "kind"));
            if !has_kind {
                let kind = BackendConfig::default().kind();
                entries.push((Value::Str("kind".into()), Value::Str(kind.into())));
            }
        }
        Ok(
            match Tagged::deserialize(value).map_err(de::Error::custom)? {
                Tagged::Analytic(c) => Self::Analytic(c),
                Tagged::Learned(c) => Self::Learned(c),
                Tagged::Vgn(c) => Self::Vgn(c),
            },
        )
    }
}

/// Any value of a self-describing format, as read.
#[derive(Debug, Clone, PartialEq)]
enum Value {
    Bool(bool),
    I64(i64),
    U64(u64),
    F64(f64),
    Str(String),
    /// JSON `null`, an absent option.
    Unit,
    Seq(Vec<Value>),
    Map(Vec<(Value, Value)>),
}

struct ValueVisitor;

impl<'de> Visitor<'de> for ValueVisitor {
    type Value = Value;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("any value")
    }

    fn visit_bool<E>(self, v: bool) -> Result<Value, E> {
        Ok(Value::Bool(v))
    }

    fn visit_i64<E>(self, v: i64) -> Result<Value, E> {
        Ok(Value::I64(v))
    }

    fn visit_u64<E>(self, v: u64) -> Result<Value, E> {
        Ok(Value::U64(v))
    }

    fn visit_f64<E>(self, v: f64) -> Result<Value, E> {
        Ok(Value::F64(v))
    }

    fn visit_str<E>(self, v: &str) -> Result<Value, E> {
        Ok(Value::Str(v.to_owned()))
    }

    fn visit_string<E>(self, v: String) -> Result<Value, E> {
        Ok(Value::Str(v))
    }

    fn visit_unit<E>(self) -> Result<Value, E> {
        Ok(Value::Unit)
    }

    fn visit_none<E>(self) -> Result<Value, E> {
        Ok(Value::Unit)
    }

    fn visit_some<D: Deserializer<'de>>(self, d: D) -> Result<Value, D::Error> {
        Value::deserialize(d)
    }

    fn visit_newtype_struct<D: Deserializer<'de>>(self, d: D) -> Result<Value, D::Error> {
        Value::deserialize(d)
    }

    fn visit_seq<A: de::SeqAccess<'de>>(self, mut seq: A) -> Result<Value, A::Error> {
        let mut items = Vec::new();
        while let Some(v) = seq.next_element()? {
            items.push(v);
        }
        Ok(Value::Seq(items))
    }

    fn visit_map<A: de::MapAccess<'de>>(self, mut map: A) -> Result<Value, A::Error> {
        let mut entries = Vec::new();
        while let Some(entry) = map.next_entry()? {
            entries.push(entry);
        }
        Ok(Value::Map(entries))
    }
}

impl<'de> Deserialize<'de> for Value {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_any(ValueVisitor)
    }
}

impl<'de> Deserializer<'de> for Value {
    type Error = de::value::Error;

    fn deserialize_any<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Self::Error> {
        match self {
            Value::Bool(v) => visitor.visit_bool(v),
            Value::I64(v) => visitor.visit_i64(v),
            Value::U64(v) => visitor.visit_u64(v),
            Value::F64(v) => visitor.visit_f64(v),
            Value::Str(v) => visitor.visit_string(v),
            Value::Unit => visitor.visit_unit(),
            Value::Seq(v) => visitor.visit_seq(SeqDeserializer::new(v.into_iter())),
            Value::Map(v) => visitor.visit_map(MapDeserializer::new(v.into_iter())),
        }
    }

    fn deserialize_option<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Self::Error> {
        match self {
            Value::Unit => visitor.visit_none(),
            v => visitor.visit_some(v),
        }
    }

    fn deserialize_newtype_struct<V: Visitor<'de>>(
        self,
        _name: &'static str,
        visitor: V,
    ) -> Result<V::Value, Self::Error> {
        visitor.visit_newtype_struct(self)
    }

    fn deserialize_enum<V: Visitor<'de>>(
        self,
        name: &'static str,
        variants: &'static [&'static str],
        visitor: V,
    ) -> Result<V::Value, Self::Error> {
        match self {
            // A unit variant (`runtime = "tract"`).
            Value::Str(s) => s
                .into_deserializer()
                .deserialize_enum(name, variants, visitor),
            v => v.deserialize_any(visitor),
        }
    }

    serde::forward_to_deserialize_any! {
        bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string bytes byte_buf
        unit unit_struct seq tuple tuple_struct map struct identifier ignored_any
    }
}

impl<'de> IntoDeserializer<'de, de::value::Error> for Value {
    type Deserializer = Self;

    fn into_deserializer(self) -> Self {
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn non_finite_floats_and_nulls_survive_the_holding() {
        // `inf` in TOML reaches the range checks as infinity (a JSON value would make it null).
        let cfg: BackendConfig =
            toml::from_str("[contact_region]\nmin_m = [0.0, inf, 0.0]\nmax_m = [1.0, 1.0, 1.0]\n")
                .unwrap();
        let BackendConfig::Analytic(a) = &cfg else {
            panic!("analytic expected")
        };
        assert_eq!(a.contact_region.unwrap().min_m[1], f32::INFINITY);
        let nan: BackendConfig = toml::from_str("kind = \"vgn\"\nmin_width_m = nan\n").unwrap();
        let BackendConfig::Vgn(v) = &nan else {
            panic!("vgn expected")
        };
        assert!(v.min_width_m.is_nan());
        let runtime: BackendConfig =
            serde_json::from_str(r#"{"kind": "learned", "runtime": "ort", "ort_library": null}"#)
                .unwrap();
        let BackendConfig::Learned(l) = &runtime else {
            panic!("learned expected")
        };
        assert_eq!(
            (l.runtime, l.ort_library.as_ref()),
            (crate::RuntimeKind::Ort, None)
        );
    }
}
