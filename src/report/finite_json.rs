//! The JSON side of [`super::finite`]: serde_json writes NaN and ±∞ as `null`, which reads back
//! as "no value", so every number of a JSON output is checked before it is written, by walking
//! the value as a serializer that looks only at floats.

use std::fmt;

use serde::ser::{self, Serialize};

use super::ReportError;

/// Checks that every float in `value` is finite; `file` names the output in the error.
///
/// # Errors
/// [`ReportError::NonFinite`] naming the file and the field path of the first NaN or ±∞.
pub fn check_json_numbers(file: &str, value: &impl Serialize) -> Result<(), ReportError> {
    let mut walker = Walker::default();
    value.serialize(&mut walker).map_err(|e| match e {
        WalkError::NonFinite(path, value) => ReportError::NonFinite {
            what: format!("{file}: `{path}`"),
            value,
        },
        WalkError::Other(message) => ReportError::NonFinite {
            what: format!("{file}: {message}"),
            value: f64::NAN,
        },
    })
}

#[derive(Default)]
struct Walker {
    path: Vec<String>,
}

#[derive(Debug)]
enum WalkError {
    NonFinite(String, f64),
    Other(String),
}

impl fmt::Display for WalkError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::NonFinite(path, v) => write!(f, "{path} is {v}"),
            Self::Other(m) => f.write_str(m),
        }
    }
}

impl std::error::Error for WalkError {}

impl ser::Error for WalkError {
    fn custom<T: fmt::Display>(msg: T) -> Self {
        Self::Other(msg.to_string())
    }
}

impl Walker {
    fn float(&self, v: f64) -> Result<(), WalkError> {
        if v.is_finite() {
            Ok(())
        } else {
            Err(WalkError::NonFinite(self.path.join("."), v))
        }
    }

    fn at<T: Serialize + ?Sized>(&mut self, key: String, value: &T) -> Result<(), WalkError> {
        self.path.push(key);
        value.serialize(&mut *self)?;
        self.path.pop();
        Ok(())
    }
}

macro_rules! ignore {
    ($($name:ident: $t:ty),*) => {
        $(fn $name(self, _: $t) -> Result<(), WalkError> { Ok(()) })*
    };
}

impl<'a> ser::Serializer for &'a mut Walker {
    type Ok = ();
    type Error = WalkError;
    type SerializeSeq = Seq<'a>;
    type SerializeTuple = Seq<'a>;
    type SerializeTupleStruct = Seq<'a>;
    type SerializeTupleVariant = Seq<'a>;
    type SerializeMap = Seq<'a>;
    type SerializeStruct = Seq<'a>;
    type SerializeStructVariant = Seq<'a>;

    ignore!(serialize_bool: bool, serialize_i8: i8, serialize_i16: i16, serialize_i32: i32,
        serialize_i64: i64, serialize_u8: u8, serialize_u16: u16, serialize_u32: u32,
        serialize_u64: u64, serialize_char: char, serialize_str: &str, serialize_bytes: &[u8],
        serialize_unit_struct: &'static str);

    fn serialize_f32(self, v: f32) -> Result<(), WalkError> {
        self.float(f64::from(v))
    }
    fn serialize_f64(self, v: f64) -> Result<(), WalkError> {
        self.float(v)
    }
    fn serialize_none(self) -> Result<(), WalkError> {
        Ok(())
    }
    fn serialize_some<T: Serialize + ?Sized>(self, value: &T) -> Result<(), WalkError> {
        value.serialize(self)
    }
    fn serialize_unit(self) -> Result<(), WalkError> {
        Ok(())
    }
    fn serialize_unit_variant(
        self,
        _: &'static str,
        _: u32,
        _: &'static str,
    ) -> Result<(), WalkError> {
        Ok(())
    }
    fn serialize_newtype_struct<T: Serialize + ?Sized>(
        self,
        _: &'static str,
        value: &T,
    ) -> Result<(), WalkError> {
        value.serialize(self)
    }
    fn serialize_newtype_variant<T: Serialize + ?Sized>(
        self,
        _: &'static str,
        _: u32,
        variant: &'static str,
        value: &T,
    ) -> Result<(), WalkError> {
        self.at(variant.to_string(), value)
    }
    fn serialize_seq(self, _: Option<usize>) -> Result<Seq<'a>, WalkError> {
        Ok(Seq::new(self))
    }
    fn serialize_tuple(self, _: usize) -> Result<Seq<'a>, WalkError> {
        Ok(Seq::new(self))
    }
    fn serialize_tuple_struct(self, _: &'static str, _: usize) -> Result<Seq<'a>, WalkError> {
        Ok(Seq::new(self))
    }
    fn serialize_tuple_variant(
        self,
        _: &'static str,
        _: u32,
        _: &'static str,
        _: usize,
    ) -> Result<Seq<'a>, WalkError> {
        Ok(Seq::new(self))
    }
    fn serialize_map(self, _: Option<usize>) -> Result<Seq<'a>, WalkError> {
        Ok(Seq::new(self))
    }
    fn serialize_struct(self, _: &'static str, _: usize) -> Result<Seq<'a>, WalkError> {
        Ok(Seq::new(self))
    }
    fn serialize_struct_variant(
        self,
        _: &'static str,
        _: u32,
        _: &'static str,
        _: usize,
    ) -> Result<Seq<'a>, WalkError> {
        Ok(Seq::new(self))
    }
}

/// Any compound value: elements numbered, fields and map entries named by their key.
struct Seq<'a> {
    walker: &'a mut Walker,
    index: usize,
    key: Option<String>,
}

impl<'a> Seq<'a> {
    fn new(walker: &'a mut Walker) -> Self {
        Self {
            walker,
            index: 0,
            key: None,
        }
    }

    fn element<T: Serialize + ?Sized>(&mut self, value: &T) -> Result<(), WalkError> {
        let key = self.key.take().unwrap_or_else(|| self.index.to_string());
        self.index += 1;
        self.walker.at(key, value)
    }
}

/// A map key as text, for the path.
fn key_text<T: Serialize + ?Sized>(key: &T) -> String {
    serde_json::to_string(key).map_or_else(|_| "?".into(), |k| k.trim_matches('"').into())
}

macro_rules! elements {
    ($($tr:ident :: $method:ident),*) => {
        $(impl ser::$tr for Seq<'_> {
            type Ok = ();
            type Error = WalkError;
            fn $method<T: Serialize + ?Sized>(&mut self, value: &T) -> Result<(), WalkError> {
                self.element(value)
            }
            fn end(self) -> Result<(), WalkError> {
                Ok(())
            }
        })*
    };
}

elements!(
    SerializeSeq::serialize_element,
    SerializeTuple::serialize_element,
    SerializeTupleStruct::serialize_field,
    SerializeTupleVariant::serialize_field
);

impl ser::SerializeMap for Seq<'_> {
    type Ok = ();
    type Error = WalkError;
    fn serialize_key<T: Serialize + ?Sized>(&mut self, key: &T) -> Result<(), WalkError> {
        self.key = Some(key_text(key));
        Ok(())
    }
    fn serialize_value<T: Serialize + ?Sized>(&mut self, value: &T) -> Result<(), WalkError> {
        self.element(value)
    }
    fn end(self) -> Result<(), WalkError> {
        Ok(())
    }
}

macro_rules! fields {
    ($($tr:ident),*) => {
        $(impl ser::$tr for Seq<'_> {
            type Ok = ();
            type Error = WalkError;
            fn serialize_field<T: Serialize + ?Sized>(
                &mut self,
                key: &'static str,
                value: &T,
            ) -> Result<(), WalkError> {
                self.key = Some(key.to_string());
                self.element(value)
            }
            fn end(self) -> Result<(), WalkError> {
                Ok(())
            }
        })*
    };
}

fields!(SerializeStruct, SerializeStructVariant);

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    #[derive(serde::Serialize)]
    struct Inner {
        values: Vec<Option<f64>>,
        by_name: BTreeMap<String, f32>,
    }

    #[derive(serde::Serialize)]
    struct Outer {
        name: String,
        inner: Vec<Inner>,
        pair: (u8, f64),
    }

    fn outer(bad: f64) -> Outer {
        Outer {
            name: "run".into(),
            inner: vec![
                Inner {
                    values: vec![Some(1.0), None],
                    by_name: BTreeMap::new(),
                },
                Inner {
                    values: vec![Some(2.0), Some(bad)],
                    by_name: [("a".to_string(), 1.5)].into(),
                },
            ],
            pair: (1, 0.5),
        }
    }

    #[test]
    fn a_non_finite_float_anywhere_is_named_by_its_path() {
        assert!(check_json_numbers("results.json", &outer(3.0)).is_ok());
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            let e = check_json_numbers("results.json", &outer(bad)).unwrap_err();
            let text = e.to_string();
            assert!(text.contains("results.json: `inner.1.values.1`"), "{text}");
        }
        let mut map = outer(1.0);
        map.inner[1].by_name.insert("b".into(), f32::NAN);
        let text = check_json_numbers("x.json", &map).unwrap_err().to_string();
        assert!(text.contains("`inner.1.by_name.b`"), "{text}");
        let mut pair = outer(1.0);
        pair.pair.1 = f64::NAN;
        let text = check_json_numbers("x.json", &pair).unwrap_err().to_string();
        assert!(text.contains("`pair.1`"), "{text}");
    }
}
