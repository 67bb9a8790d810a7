//! CDR with the 4-byte encapsulation header, as DDS and rosbag2 carry ROS 2 messages.

use byteorder::{BigEndian, LittleEndian};
use serde::{de::DeserializeOwned, Serialize};

/// Encapsulation identifiers (DDS-XTypes 7.6.3.1.2): plain CDR, big- and little-endian.
const CDR_BE: [u8; 2] = [0x00, 0x00];
const CDR_LE: [u8; 2] = [0x00, 0x01];

#[derive(Debug, thiserror::Error)]
pub enum CdrError {
    #[error("{len} bytes is shorter than the 4-byte CDR encapsulation header")]
    Short { len: usize },
    #[error("encapsulation {0:02x}{1:02x} is not plain CDR (0000 or 0001)")]
    Encapsulation(u8, u8),
    #[error("CDR does not match the message's schema: {0}")]
    Schema(#[from] cdr_encoding::Error),
}

/// A message as little-endian CDR with its encapsulation header.
pub fn encode<M: Serialize>(message: &M) -> Result<Vec<u8>, CdrError> {
    let mut bytes = CDR_LE.to_vec();
    bytes.extend_from_slice(&[0, 0]);
    cdr_encoding::to_writer::<M, LittleEndian, _>(&mut bytes, message)?;
    Ok(bytes)
}

/// A message from CDR with its encapsulation header, either byte order. A length field cannot make
/// this allocate more than the input holds.
pub fn decode<M: DeserializeOwned>(bytes: &[u8]) -> Result<M, CdrError> {
    let [a, b, _, _, body @ ..] = bytes else {
        return Err(CdrError::Short { len: bytes.len() });
    };
    let (message, _) = match [*a, *b] {
        CDR_LE => cdr_encoding::from_bytes::<M, LittleEndian>(body)?,
        CDR_BE => cdr_encoding::from_bytes::<M, BigEndian>(body)?,
        _ => return Err(CdrError::Encapsulation(*a, *b)),
    };
    Ok(message)
}
