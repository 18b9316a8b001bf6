//! The CRC of SDO block transfers: CRC-16/CCITT with polynomial
//! x^16 + x^12 + x^5 + 1 (0x1021), initial value 0, no reflection, no final
//! XOR (the variant also known as CRC-16/XMODEM), as CiA 301 specifies.

/// Continues a CRC over more bytes; start with `0`.
pub fn crc16_update(mut crc: u16, data: &[u8]) -> u16 {
    for &byte in data {
        crc ^= u16::from(byte) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x1021
            } else {
                crc << 1
            };
        }
    }
    crc
}

/// The block transfer CRC of `data`.
pub fn crc16(data: &[u8]) -> u16 {
    crc16_update(0, data)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn check_value_and_incremental() {
        // The catalogue check value of CRC-16/XMODEM.
        assert_eq!(crc16(b"123456789"), 0x31C3);
        assert_eq!(crc16(b""), 0);
        assert_eq!(crc16_update(crc16(b"1234"), b"56789"), 0x31C3);
    }
}
