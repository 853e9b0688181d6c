//! CRC-32C (Castagnoli, reflected polynomial 0x82F63B78), the checksum of TFRecord framing, and
//! its *masked* form (TensorFlow's `crc32c::Mask`: rotated right by 15 bits plus a constant, so
//! that a CRC stored next to the data it covers does not checksum to a fixed value).

const POLY: u32 = 0x82F6_3B78;
const MASK_DELTA: u32 = 0xA282_EAD8;

const TABLE: [u32; 256] = {
    let mut t = [0u32; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = i as u32;
        let mut k = 0;
        while k < 8 {
            c = if c & 1 != 0 { (c >> 1) ^ POLY } else { c >> 1 };
            k += 1;
        }
        t[i] = c;
        i += 1;
    }
    t
};

/// The CRC-32C of `data`.
pub fn crc32c(data: &[u8]) -> u32 {
    let mut c = !0u32;
    for &b in data {
        c = TABLE[((c ^ b as u32) & 0xff) as usize] ^ (c >> 8);
    }
    !c
}

/// The masked CRC-32C of `data`, as TFRecord stores it.
pub fn masked(data: &[u8]) -> u32 {
    crc32c(data).rotate_right(15).wrapping_add(MASK_DELTA)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_values() {
        // The check value of CRC-32C and RFC 3720's test patterns (B.4).
        assert_eq!(crc32c(b"123456789"), 0xE306_9283);
        assert_eq!(crc32c(&[0u8; 32]), 0x8A91_36AA);
        assert_eq!(crc32c(&[0xffu8; 32]), 0x62A8_AB43);
        let ascending: Vec<u8> = (0..32).collect();
        assert_eq!(crc32c(&ascending), 0x46DD_794E);
        assert_eq!(crc32c(b""), 0);
    }

    #[test]
    fn the_mask_is_tensorflows() {
        // TensorFlow's ((crc >> 15) | (crc << 17)) + 0xa282ead8 of 0xE3069283, worked out by
        // hand (Python: ((c >> 15 | c << 17) & 0xffffffff) + 0xa282ead8 & 0xffffffff).
        assert_eq!(masked(b"123456789"), 0xC78A_B0E5);
        assert_ne!(masked(b"a"), crc32c(b"a"));
    }
}
