//! Samples cross rustdds as raw bytes: `sensor_io::unitree_hg::cdr` is the one codec for the
//! unitree_hg messages (serde cannot derive their 35-element arrays, and a second codec would be a
//! second truth). The adapter only puts the 4-byte encapsulation header back in front of the
//! payload rustdds hands over, so the codec sees the sample exactly as it was on the wire.
use std::convert::Infallible;

use rustdds::no_key::{Decode, DefaultDecoder, DeserializerAdapter, SerializerAdapter};
use rustdds::RepresentationIdentifier as Rep;

/// One sample: encapsulation header (4 bytes) + payload.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CdrSample(pub Vec<u8>);

/// Serializer and deserializer adapter for [`CdrSample`].
pub struct RawCdr;

/// Every encoding is taken in, so that one our codec refuses (XCDR2, parameter lists) is reported
/// as a malformed frame instead of vanishing inside the DDS library.
const ENCODINGS: [Rep; 8] = [
    Rep::CDR_LE,
    Rep::CDR_BE,
    Rep::PL_CDR_LE,
    Rep::PL_CDR_BE,
    Rep::CDR2_LE,
    Rep::CDR2_BE,
    Rep::XCDR2_LE,
    Rep::XCDR2_BE,
];

impl DeserializerAdapter<CdrSample> for RawCdr {
    type Error = Infallible;
    type Decoded = CdrSample;

    fn supported_encodings() -> &'static [Rep] {
        &ENCODINGS
    }

    fn transform_decoded(decoded: CdrSample) -> CdrSample {
        decoded
    }
}

#[derive(Clone, Copy)]
pub struct RawDecoder;

impl<'de> Decode<'de, CdrSample> for RawDecoder {
    type Error = Infallible;

    fn decode_bytes(self, input: &'de [u8], encoding: Rep) -> Result<CdrSample, Infallible> {
        let mut v = Vec::with_capacity(4 + input.len());
        v.extend_from_slice(&encoding.to_bytes());
        v.extend_from_slice(&[0, 0]);
        v.extend_from_slice(input);
        Ok(CdrSample(v))
    }
}

impl DefaultDecoder<CdrSample> for RawCdr {
    type Decoder = RawDecoder;
    const DECODER: RawDecoder = RawDecoder;
}

impl SerializerAdapter<CdrSample> for RawCdr {
    type Error = Infallible;

    fn output_encoding() -> Rep {
        Rep::CDR_LE
    }

    fn to_bytes(value: &CdrSample) -> Result<rustdds::bytes::Bytes, Infallible> {
        // Our codec writes the little-endian header itself; rustdds writes it again from
        // `output_encoding`.
        Ok(rustdds::bytes::Bytes::copy_from_slice(value.0.get(4..).unwrap_or(&[])))
    }
}
