//! Deterministic sample messages with a distinct value in every field, for tests and benchmarks of
//! every type: a serde deserializer that makes values up instead of reading them.

use serde::de::{self, DeserializeOwned, DeserializeSeed, Visitor};
use std::fmt;

/// A message whose fields hold distinct values derived from `seed`: integers count up, floats
/// are not dyadic (so a lossy round trip shows), strings are `s<n>`, sequences have 1 to 3 items.
pub fn message<M: DeserializeOwned>(seed: u64) -> M {
    let mut filler = Filler { next: seed.wrapping_mul(1000) + 1 };
    match M::deserialize(&mut filler) {
        Ok(message) => message,
        Err(Unsupported(what)) => panic!("sample::message cannot make {what}"),
    }
}

struct Filler {
    next: u64,
}

impl Filler {
    fn take(&mut self) -> u64 {
        self.next += 1;
        self.next
    }
}

#[derive(Debug)]
struct Unsupported(String);

impl fmt::Display for Unsupported {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Unsupported {}

impl de::Error for Unsupported {
    fn custom<T: fmt::Display>(message: T) -> Self {
        Self(message.to_string())
    }
}

struct Items<'a> {
    filler: &'a mut Filler,
    left: usize,
}

impl<'de> de::SeqAccess<'de> for Items<'_> {
    type Error = Unsupported;
    fn next_element_seed<T: DeserializeSeed<'de>>(&mut self, seed: T) -> Result<Option<T::Value>, Unsupported> {
        if self.left == 0 {
            return Ok(None);
        }
        self.left -= 1;
        seed.deserialize(&mut *self.filler).map(Some)
    }
}

macro_rules! integer {
    ($method:ident, $visit:ident, $ty:ty) => {
        fn $method<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Unsupported> {
            let n = self.take();
            visitor.$visit((n % (<$ty>::MAX as u64 / 2)) as $ty)
        }
    };
}

impl<'de> de::Deserializer<'de> for &mut Filler {
    type Error = Unsupported;

    integer!(deserialize_u8, visit_u8, u8);
    integer!(deserialize_u16, visit_u16, u16);
    integer!(deserialize_u32, visit_u32, u32);
    integer!(deserialize_u64, visit_u64, u64);
    integer!(deserialize_i8, visit_i8, i8);
    integer!(deserialize_i16, visit_i16, i16);
    integer!(deserialize_i32, visit_i32, i32);
    integer!(deserialize_i64, visit_i64, i64);

    fn deserialize_f32<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Unsupported> {
        // Dyadic: f32 values print and parse exactly through JSON's f64.
        let n = self.take();
        visitor.visit_f32(n as f32 + 0.25)
    }

    fn deserialize_f64<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Unsupported> {
        let n = self.take();
        visitor.visit_f64(n as f64 + 1.0 / 3.0)
    }

    fn deserialize_bool<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Unsupported> {
        let n = self.take();
        visitor.visit_bool(n % 2 == 1)
    }

    fn deserialize_string<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Unsupported> {
        let n = self.take();
        visitor.visit_string(format!("s{n}"))
    }

    fn deserialize_str<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Unsupported> {
        self.deserialize_string(visitor)
    }

    fn deserialize_byte_buf<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Unsupported> {
        let n = self.take();
        let len = 3 + (n % 5) as usize;
        visitor.visit_byte_buf((0..len).map(|i| (n as usize * 7 + i) as u8).collect())
    }

    fn deserialize_bytes<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Unsupported> {
        self.deserialize_byte_buf(visitor)
    }

    fn deserialize_seq<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Unsupported> {
        let left = 1 + (self.take() % 3) as usize;
        visitor.visit_seq(Items { filler: self, left })
    }

    fn deserialize_tuple<V: Visitor<'de>>(self, len: usize, visitor: V) -> Result<V::Value, Unsupported> {
        visitor.visit_seq(Items { filler: self, left: len })
    }

    fn deserialize_struct<V: Visitor<'de>>(
        self,
        _name: &'static str,
        fields: &'static [&'static str],
        visitor: V,
    ) -> Result<V::Value, Unsupported> {
        self.deserialize_tuple(fields.len(), visitor)
    }

    fn deserialize_newtype_struct<V: Visitor<'de>>(
        self,
        _name: &'static str,
        visitor: V,
    ) -> Result<V::Value, Unsupported> {
        visitor.visit_newtype_struct(self)
    }

    fn deserialize_any<V: Visitor<'de>>(self, _visitor: V) -> Result<V::Value, Unsupported> {
        Err(Unsupported("a value of unknown type".into()))
    }

    serde::forward_to_deserialize_any! {
        i128 u128 char option unit unit_struct tuple_struct map enum identifier ignored_any
    }
}
