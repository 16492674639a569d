//! Unitree's CRC32 for unitree_hg messages: CRC-32/MPEG-2 parameters (poly 0x04C11DB7, init
//! 0xFFFFFFFF, MSB first, no final XOR) fed with the message as little-endian u32 words, each word
//! processed from its most significant bit. It is *not* the common reflected CRC-32.

const POLY: u32 = 0x04C1_1DB7;

/// Byte-at-a-time table, built at compile time.
const TABLE: [u32; 256] = {
    let mut table = [0u32; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = (i as u32) << 24;
        let mut b = 0;
        while b < 8 {
            c = if c & 0x8000_0000 != 0 { (c << 1) ^ POLY } else { c << 1 };
            b += 1;
        }
        table[i] = c;
        i += 1;
    }
    table
};

/// CRC over `words.len() / 4` little-endian u32 words of `bytes` (length must be a multiple of 4;
/// trailing bytes are ignored).
pub fn crc32_words(bytes: &[u8]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for w in bytes.chunks_exact(4) {
        // The word's MSB comes first: feed its bytes in big-endian order.
        for &b in [w[3], w[2], w[1], w[0]].iter() {
            crc = (crc << 8) ^ TABLE[((crc >> 24) ^ b as u32) as usize];
        }
    }
    crc
}

/// Literal transcription of the SDK's bit-serial `crc32_core`, kept as a test oracle.
#[cfg(test)]
pub(crate) fn crc32_core_reference(words: &[u32]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for &data in words {
        let mut xbit = 1u32 << 31;
        for _ in 0..32 {
            if crc & 0x8000_0000 != 0 {
                crc <<= 1;
                crc ^= POLY;
            } else {
                crc <<= 1;
            }
            if data & xbit != 0 {
                crc ^= POLY;
            }
            xbit >>= 1;
        }
    }
    crc
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn words(bytes: &[u8]) -> Vec<u32> {
        bytes
            .chunks_exact(4)
            .map(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]]))
            .collect()
    }

    /// Independent implementation: the `crc` crate's CRC-32/MPEG-2 over each word's big-endian bytes.
    fn crc_crate(bytes: &[u8]) -> u32 {
        let swapped: Vec<u8> = bytes.chunks_exact(4).flat_map(|w| [w[3], w[2], w[1], w[0]]).collect();
        crc::Crc::<u32>::new(&crc::CRC_32_MPEG_2).checksum(&swapped)
    }

    #[test]
    fn known_vector() {
        // CRC-32/MPEG-2 check value over "123456789" is 0x0376E6E7; with our word order that is the
        // CRC of the words whose big-endian bytes spell the string.
        let be = b"12345678";
        let le: Vec<u8> = be.chunks_exact(4).flat_map(|w| [w[3], w[2], w[1], w[0]]).collect();
        assert_eq!(crc32_words(&le), crc::Crc::<u32>::new(&crc::CRC_32_MPEG_2).checksum(be));
        assert_eq!(
            crc::Crc::<u32>::new(&crc::CRC_32_MPEG_2).checksum(b"123456789"),
            0x0376_E6E7
        );
    }

    proptest! {
        #[test]
        fn table_matches_bitwise_sdk_and_crc_crate(data in proptest::collection::vec(any::<u8>(), 0..600)) {
            let n = data.len() / 4 * 4;
            let data = &data[..n];
            let ours = crc32_words(data);
            prop_assert_eq!(ours, crc32_core_reference(&words(data)));
            prop_assert_eq!(ours, crc_crate(data));
        }
    }
}
