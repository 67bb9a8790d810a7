//! Messages as CDR bytes, for tools that meet types at run time (`bag play`, `bag record`).

use ros2_client::dds::rustdds::{
    self,
    no_key::{Decode, DefaultDecoder, DeserializerAdapter, SerializerAdapter},
    RepresentationIdentifier,
};

/// One message's CDR payload and its encapsulation (the 2-byte representation identifier).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RawCdr {
    pub representation: [u8; 2],
    pub payload: Vec<u8>,
}

impl RawCdr {
    /// From CDR as rosbag2 stores it (a 4-byte encapsulation header, then the payload); `None`
    /// when the header is missing or not little-endian CDR, the only encoding DDS writers here
    /// send.
    pub fn from_encapsulated(data: &[u8]) -> Option<RawCdr> {
        let (header, payload) = data.split_at_checked(4)?;
        let representation = [header[0], header[1]];
        (representation == RepresentationIdentifier::CDR_LE.to_bytes())
            .then(|| RawCdr { representation, payload: payload.to_vec() })
    }

    /// As rosbag2 stores it: the encapsulation header, then the payload.
    pub fn encapsulated(&self) -> Vec<u8> {
        let mut data = Vec::with_capacity(4 + self.payload.len());
        data.extend_from_slice(&self.representation);
        data.extend_from_slice(&[0, 0]);
        data.extend_from_slice(&self.payload);
        data
    }
}

/// Passes [`RawCdr`] between RustDDS and the caller untouched.
pub struct RawAdapter;

#[derive(Debug, thiserror::Error)]
#[error("raw CDR cannot fail")]
pub struct Never;

impl SerializerAdapter<RawCdr> for RawAdapter {
    type Error = Never;

    fn output_encoding() -> RepresentationIdentifier {
        RepresentationIdentifier::CDR_LE
    }

    fn to_bytes(value: &RawCdr) -> Result<rustdds::bytes::Bytes, Never> {
        Ok(rustdds::bytes::Bytes::copy_from_slice(&value.payload))
    }
}

impl DeserializerAdapter<RawCdr> for RawAdapter {
    type Error = Never;
    type Decoded = RawCdr;

    fn supported_encodings() -> &'static [RepresentationIdentifier] {
        &[RepresentationIdentifier::CDR_LE, RepresentationIdentifier::CDR_BE]
    }

    fn transform_decoded(decoded: RawCdr) -> RawCdr {
        decoded
    }
}

impl DefaultDecoder<RawCdr> for RawAdapter {
    type Decoder = RawDecoder;
    const DECODER: RawDecoder = RawDecoder;
}

#[derive(Clone)]
pub struct RawDecoder;

impl Decode<'_, RawCdr> for RawDecoder {
    type Error = Never;

    fn decode_bytes(self, input: &[u8], encoding: RepresentationIdentifier) -> Result<RawCdr, Never> {
        Ok(RawCdr { representation: encoding.to_bytes(), payload: input.to_vec() })
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn bag_cdr_round_trips_and_big_endian_is_refused() {
        let time = revisit_msgs::builtin_interfaces::Time { sec: 3, nanosec: 4 };
        let data = revisit_msgs::encode(&time).unwrap();
        let raw = RawCdr::from_encapsulated(&data).unwrap();
        assert_eq!(raw.payload.len(), 8);
        assert_eq!(raw.encapsulated(), data);
        assert_eq!(RawCdr::from_encapsulated(&[0, 0, 0, 0, 1]), None);
        assert_eq!(RawCdr::from_encapsulated(&[0, 1]), None);
    }
}
