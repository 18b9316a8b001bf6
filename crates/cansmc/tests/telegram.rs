//! Telegram codec: exact byte vectors built from the spec's field tables,
//! rejection of malformed frames, and round trips.

use cangate_can::{CanId, Frame};
use cangate_cansmc::{
    Channel, CodecError, Command, ControlWord, CycleCounter, Feedback, Function, ParameterAccess,
    RejectReason, SmcAddress, StatusWord, Telegram,
};
use proptest::prelude::*;

fn addr(a: u8) -> SmcAddress {
    SmcAddress::new(a).unwrap()
}

fn frame(id: u16, data: &[u8]) -> Frame {
    Frame::new(CanId::Standard(id), data).unwrap()
}

/// Encodes, checks id and bytes, and decodes back on the telegram's channel.
fn both_ways(t: Telegram, id: u16, bytes: &[u8]) {
    let f = t.encode();
    assert_eq!(f.id(), CanId::Standard(id), "{t:?}");
    assert_eq!(f.data(), bytes, "{t:?}");
    assert!(!f.is_fd() && !f.is_remote());
    assert_eq!(Telegram::decode(&frame(id, bytes), t.channel()), Ok(t));
}

/// enable + fault reset, counter 0xA: bits 0, 2, 12..15 -> 0xA005 -> LE 05 A0.
fn cw() -> ControlWord {
    ControlWord {
        enable: true,
        halt: false,
        fault_reset: true,
        counter: CycleCounter::new(0xA),
    }
}

/// ready + enabled + target reached + homed, echo 0xA -> 0xA01B -> LE 1B A0.
fn sw() -> StatusWord {
    StatusWord {
        ready: true,
        enabled: true,
        target_reached: true,
        homed: true,
        counter_echo: CycleCounter::new(0xA),
        ..StatusWord::default()
    }
}

#[test]
fn identifier_layout() {
    assert_eq!(Function::Mst.can_id(0x3F), 0x03F);
    assert_eq!(Function::Position.can_id(5), (0x02 << 6) | 5);
    assert_eq!(Function::Reject.can_id(61), 0x7FD);
    assert_eq!(Function::User.can_id(1), 0x201);
}

#[test]
fn slave_address_range() {
    assert_eq!(SmcAddress::new(0), Err(CodecError::BadSlaveAddress(0)));
    assert!(SmcAddress::new(1).is_ok());
    assert!(SmcAddress::new(61).is_ok());
    assert_eq!(SmcAddress::new(62), Err(CodecError::BadSlaveAddress(62)));
    assert_eq!(SmcAddress::new(63), Err(CodecError::BadSlaveAddress(63)));
}

#[test]
fn cycle_counter_wraps() {
    let mut c = CycleCounter::default();
    for _ in 0..15 {
        c = c.next();
    }
    assert_eq!(c.get(), 15);
    assert_eq!(c.next().get(), 0);
    assert_eq!(CycleCounter::new(0x1F).get(), 0xF);
}

#[test]
fn control_and_status_words() {
    assert_eq!(cw().to_bits(false), 0xA005);
    assert_eq!(cw().to_bits(true), 0xA00D);
    let halt = ControlWord {
        halt: true,
        ..ControlWord::default()
    };
    assert_eq!(halt.to_bits(false), 0x0002);
    assert_eq!(sw().to_bits(), 0xA01B);
    let all = StatusWord {
        ready: true,
        enabled: true,
        fault: true,
        target_reached: true,
        homed: true,
        following_error: true,
        parameter_error: true,
        counter_echo: CycleCounter::new(0xF),
    };
    assert_eq!(all.to_bits(), 0xF07F);
    assert_eq!(StatusWord::from_bits(0xF07F), Ok(all));
}

#[test]
fn mst() {
    both_ways(Telegram::Mst, 0x03F, &[]);
}

#[test]
fn mct_and_dct() {
    // MCT to slave 3: 2000 µs = 0x7D0, 10 slaves.
    both_ways(
        Telegram::Master {
            to: addr(3),
            control: cw(),
            command: Command::Connect {
                cycle_time_us: 2000,
                slave_count: 10,
            },
        },
        0x043,
        &[0x05, 0xA0, 0xD0, 0x07, 0x00, 0x00, 0x0A, 0x00],
    );
    // DCT from slave 3: device type 0x1234, firmware 0x0102.
    both_ways(
        Telegram::Slave {
            from: addr(3),
            status: sw(),
            feedback: Feedback::Connect {
                device_type: 0x1234,
                firmware_version: 0x0102,
            },
        },
        0x043,
        &[0x1B, 0xA0, 0x34, 0x12, 0x02, 0x01, 0x00, 0x00],
    );
}

#[test]
fn position() {
    both_ways(
        Telegram::Master {
            to: addr(61),
            control: cw(),
            command: Command::Position(-2),
        },
        0x0BD,
        &[0x05, 0xA0, 0xFE, 0xFF, 0xFF, 0xFF, 0x00, 0x00],
    );
    both_ways(
        Telegram::Slave {
            from: addr(61),
            status: sw(),
            feedback: Feedback::Position(0x0102_0304),
        },
        0x0BD,
        &[0x1B, 0xA0, 0x04, 0x03, 0x02, 0x01, 0x00, 0x00],
    );
}

#[test]
fn velocity() {
    both_ways(
        Telegram::Master {
            to: addr(1),
            control: cw(),
            command: Command::Velocity(1500),
        },
        0x0C1,
        &[0x05, 0xA0, 0xDC, 0x05, 0x00, 0x00, 0x00, 0x00],
    );
    both_ways(
        Telegram::Slave {
            from: addr(1),
            status: sw(),
            feedback: Feedback::Velocity(-1500),
        },
        0x0C1,
        &[0x1B, 0xA0, 0x24, 0xFA, 0xFF, 0xFF, 0x00, 0x00],
    );
}

#[test]
fn homing() {
    both_ways(
        Telegram::Master {
            to: addr(2),
            control: cw(),
            command: Command::Homing { method: 35 },
        },
        0x102,
        &[0x05, 0xA0, 0x23, 0x00, 0x00, 0x00, 0x00, 0x00],
    );
    both_ways(
        Telegram::Slave {
            from: addr(2),
            status: sw(),
            feedback: Feedback::Homing(100),
        },
        0x102,
        &[0x1B, 0xA0, 0x64, 0x00, 0x00, 0x00, 0x00, 0x00],
    );
}

#[test]
fn parameter() {
    // Read parameter 4: bit 3 clear, value 0.
    both_ways(
        Telegram::Master {
            to: addr(7),
            control: cw(),
            command: Command::Parameter {
                access: ParameterAccess::Read,
                number: 4,
                value: 0,
            },
        },
        0x147,
        &[0x05, 0xA0, 0x04, 0x00, 0x00, 0x00, 0x00, 0x00],
    );
    // Write parameter 0x1000 = -1: bit 3 set.
    both_ways(
        Telegram::Master {
            to: addr(7),
            control: cw(),
            command: Command::Parameter {
                access: ParameterAccess::Write,
                number: 0x1000,
                value: -1,
            },
        },
        0x147,
        &[0x0D, 0xA0, 0x00, 0x10, 0xFF, 0xFF, 0xFF, 0xFF],
    );
    // Answer with parameter error (bit 6).
    both_ways(
        Telegram::Slave {
            from: addr(7),
            status: StatusWord {
                parameter_error: true,
                ..sw()
            },
            feedback: Feedback::Parameter {
                number: 3,
                value: 10_000,
            },
        },
        0x147,
        &[0x5B, 0xA0, 0x03, 0x00, 0x10, 0x27, 0x00, 0x00],
    );
}

#[test]
fn io() {
    both_ways(
        Telegram::Master {
            to: addr(9),
            control: cw(),
            command: Command::Io {
                outputs: 0x8000_0001,
                mask: 0xFFFF,
            },
        },
        0x189,
        &[0x05, 0xA0, 0x01, 0x00, 0x00, 0x80, 0xFF, 0xFF],
    );
    both_ways(
        Telegram::Slave {
            from: addr(9),
            status: sw(),
            feedback: Feedback::Io {
                inputs: 0x00AA_0055,
            },
        },
        0x189,
        &[0x1B, 0xA0, 0x55, 0x00, 0xAA, 0x00, 0x00, 0x00],
    );
}

#[test]
fn encoder() {
    both_ways(
        Telegram::Master {
            to: addr(10),
            control: cw(),
            command: Command::Encoder,
        },
        0x1CA,
        &[0x05, 0xA0, 0, 0, 0, 0, 0, 0],
    );
    both_ways(
        Telegram::Slave {
            from: addr(10),
            status: sw(),
            feedback: Feedback::Encoder(i32::MIN),
        },
        0x1CA,
        &[0x1B, 0xA0, 0x00, 0x00, 0x00, 0x80, 0x00, 0x00],
    );
}

#[test]
fn user() {
    both_ways(
        Telegram::Master {
            to: addr(11),
            control: cw(),
            command: Command::User([1, 2, 3, 4, 5, 6]),
        },
        0x20B,
        &[0x05, 0xA0, 1, 2, 3, 4, 5, 6],
    );
    both_ways(
        Telegram::Slave {
            from: addr(11),
            status: sw(),
            feedback: Feedback::User([0xFF; 6]),
        },
        0x20B,
        &[0x1B, 0xA0, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF],
    );
}

#[test]
fn reject() {
    // Slave 12 rejects homing (0x04), reason 2 = not enabled; id 0x1F<<6|12.
    both_ways(
        Telegram::Slave {
            from: addr(12),
            status: StatusWord {
                ready: true,
                ..StatusWord::default()
            },
            feedback: Feedback::Reject {
                function: Function::Homing,
                reason: RejectReason::NotEnabled,
            },
        },
        0x7CC,
        &[0x01, 0x00, 0x04, 0x02, 0x00, 0x00, 0x00, 0x00],
    );
}

fn dec(id: u16, data: &[u8], ch: Channel) -> Result<Telegram, CodecError> {
    Telegram::decode(&frame(id, data), ch)
}

const POS_OK: [u8; 8] = [0x05, 0xA0, 1, 2, 3, 4, 0, 0];

#[test]
fn rejects_frame_formats() {
    let ext = Frame::new(CanId::Extended(0x0BD), &POS_OK).unwrap();
    assert_eq!(
        Telegram::decode(&ext, Channel::Command),
        Err(CodecError::ExtendedId(0x0BD))
    );
    let rtr = Frame::new_remote(CanId::Standard(0x0BD), 8).unwrap();
    assert_eq!(
        Telegram::decode(&rtr, Channel::Command),
        Err(CodecError::Remote(0x0BD))
    );
    let fd = Frame::new_fd(CanId::Standard(0x0BD), &POS_OK, false, false).unwrap();
    assert_eq!(
        Telegram::decode(&fd, Channel::Command),
        Err(CodecError::Fd(0x0BD))
    );
    let err = Frame::new_error(0x4, [0; 8]);
    assert_eq!(
        Telegram::decode(&err, Channel::Status),
        Err(CodecError::ErrorFrame)
    );
}

#[test]
fn rejects_wrong_length() {
    assert_eq!(
        dec(0x0BD, &POS_OK[..7], Channel::Command),
        Err(CodecError::WrongLength {
            function: Function::Position,
            expected: 8,
            got: 7
        })
    );
    assert_eq!(
        dec(0x03F, &[0], Channel::Command),
        Err(CodecError::WrongLength {
            function: Function::Mst,
            expected: 0,
            got: 1
        })
    );
    assert!(matches!(
        dec(0x7CC, &[], Channel::Status),
        Err(CodecError::WrongLength { .. })
    ));
}

#[test]
fn rejects_unknown_function() {
    for code in [0x09u8, 0x10, 0x1E] {
        assert_eq!(
            dec((u16::from(code) << 6) | 1, &POS_OK, Channel::Command),
            Err(CodecError::UnknownFunction(code))
        );
    }
}

#[test]
fn rejects_bad_addresses() {
    for a in [0u8, 0x3E, 0x3F] {
        assert_eq!(
            dec(Function::Position.can_id(a), &POS_OK, Channel::Command),
            Err(CodecError::BadAddress {
                function: Function::Position,
                address: a
            })
        );
    }
    // MST must be broadcast.
    assert_eq!(
        dec(0x001, &[], Channel::Command),
        Err(CodecError::BadAddress {
            function: Function::Mst,
            address: 1
        })
    );
}

#[test]
fn rejects_wrong_channel() {
    assert_eq!(
        dec(0x03F, &[], Channel::Status),
        Err(CodecError::WrongChannel {
            function: Function::Mst,
            channel: Channel::Status
        })
    );
    assert_eq!(
        dec(0x7CC, &[1, 0, 4, 2, 0, 0, 0, 0], Channel::Command),
        Err(CodecError::WrongChannel {
            function: Function::Reject,
            channel: Channel::Command
        })
    );
}

#[test]
fn rejects_reserved_bits_and_bytes() {
    // Control word bit 4 set.
    assert_eq!(
        dec(0x0BD, &[0x15, 0xA0, 1, 2, 3, 4, 0, 0], Channel::Command),
        Err(CodecError::ReservedBits {
            word: "control word",
            bits: 0x0010
        })
    );
    // Status word bit 7 set.
    assert_eq!(
        dec(0x0BD, &[0x80, 0x00, 1, 2, 3, 4, 0, 0], Channel::Status),
        Err(CodecError::ReservedBits {
            word: "status word",
            bits: 0x0080
        })
    );
    // Parameter-write bit on a position MDT.
    assert_eq!(
        dec(0x0BD, &[0x08, 0x00, 1, 2, 3, 4, 0, 0], Channel::Command),
        Err(CodecError::WriteBitOutsideParameter(Function::Position))
    );
    // Reserved byte 7 of a position MDT.
    assert_eq!(
        dec(0x0BD, &[0x05, 0xA0, 1, 2, 3, 4, 0, 9], Channel::Command),
        Err(CodecError::ReservedByte {
            function: Function::Position,
            index: 7,
            value: 9
        })
    );
    // Reserved byte 3 of a homing MDT.
    assert!(matches!(
        dec(0x102, &[0, 0, 35, 1, 0, 0, 0, 0], Channel::Command),
        Err(CodecError::ReservedByte { index: 3, .. })
    ));
    // Reserved byte 7 of an MCT.
    assert!(matches!(
        dec(0x043, &[0, 0, 0xD0, 7, 0, 0, 10, 1], Channel::Command),
        Err(CodecError::ReservedByte { index: 7, .. })
    ));
}

#[test]
fn rejects_bad_reject_payload() {
    assert_eq!(
        dec(0x7CC, &[0, 0, 0x04, 4, 0, 0, 0, 0], Channel::Status),
        Err(CodecError::BadRejectReason(4))
    );
    for f in [0x00u8, 0x1F, 0x09] {
        assert_eq!(
            dec(0x7CC, &[0, 0, f, 1, 0, 0, 0, 0], Channel::Status),
            Err(CodecError::BadRejectedFunction(f))
        );
    }
}

fn arb_function() -> impl Strategy<Value = Function> {
    prop_oneof![
        Just(Function::Connection),
        Just(Function::Position),
        Just(Function::Velocity),
        Just(Function::Homing),
        Just(Function::Parameter),
        Just(Function::Io),
        Just(Function::Encoder),
        Just(Function::User),
    ]
}

fn arb_command() -> impl Strategy<Value = Command> {
    prop_oneof![
        (any::<u32>(), any::<u8>()).prop_map(|(cycle_time_us, slave_count)| Command::Connect {
            cycle_time_us,
            slave_count
        }),
        any::<i32>().prop_map(Command::Position),
        any::<i32>().prop_map(Command::Velocity),
        any::<u8>().prop_map(|method| Command::Homing { method }),
        (any::<bool>(), any::<u16>(), any::<i32>()).prop_map(|(w, number, value)| {
            Command::Parameter {
                access: if w {
                    ParameterAccess::Write
                } else {
                    ParameterAccess::Read
                },
                number,
                value,
            }
        }),
        (any::<u32>(), any::<u16>()).prop_map(|(outputs, mask)| Command::Io { outputs, mask }),
        Just(Command::Encoder),
        any::<[u8; 6]>().prop_map(Command::User),
    ]
}

fn arb_feedback() -> impl Strategy<Value = Feedback> {
    prop_oneof![
        (any::<u16>(), any::<u16>()).prop_map(|(device_type, firmware_version)| {
            Feedback::Connect {
                device_type,
                firmware_version,
            }
        }),
        any::<i32>().prop_map(Feedback::Position),
        any::<i32>().prop_map(Feedback::Velocity),
        any::<i32>().prop_map(Feedback::Homing),
        (any::<u16>(), any::<i32>())
            .prop_map(|(number, value)| Feedback::Parameter { number, value }),
        any::<u32>().prop_map(|inputs| Feedback::Io { inputs }),
        any::<i32>().prop_map(Feedback::Encoder),
        any::<[u8; 6]>().prop_map(Feedback::User),
        (arb_function(), 1u8..=3).prop_map(|(function, r)| Feedback::Reject {
            function,
            reason: RejectReason::from_code(r).unwrap(),
        }),
    ]
}

fn arb_telegram() -> impl Strategy<Value = Telegram> {
    let address = (1u8..=61).prop_map(addr);
    prop_oneof![
        Just(Telegram::Mst),
        (
            address.clone(),
            any::<(bool, bool, bool)>(),
            0u8..16,
            arb_command()
        )
            .prop_map(|(to, (enable, halt, fault_reset), c, command)| {
                Telegram::Master {
                    to,
                    control: ControlWord {
                        enable,
                        halt,
                        fault_reset,
                        counter: CycleCounter::new(c),
                    },
                    command,
                }
            }),
        (address, 0u8..0x80, 0u8..16, arb_feedback()).prop_map(|(from, flags, c, feedback)| {
            let bits = u16::from(flags) | (u16::from(c) << 12);
            Telegram::Slave {
                from,
                status: StatusWord::from_bits(bits).unwrap(),
                feedback,
            }
        }),
    ]
}

proptest! {
    #[test]
    fn round_trip(t in arb_telegram()) {
        let f = t.encode();
        prop_assert_eq!(Telegram::decode(&f, t.channel()), Ok(t));
    }

    /// Whatever arbitrary frame decodes re-encodes to exactly the same frame
    /// (strict decoding loses nothing).
    #[test]
    fn decode_is_canonical(id in 0u16..=0x7FF, len in 0usize..=8, data in any::<[u8; 8]>(), status in any::<bool>()) {
        let f = frame(id, &data[..len]);
        let ch = if status { Channel::Status } else { Channel::Command };
        if let Ok(t) = Telegram::decode(&f, ch) {
            prop_assert_eq!(t.encode(), f);
            prop_assert_eq!(t.channel(), ch);
        }
    }

    /// Frames biased towards valid heads still never panic and re-encode.
    #[test]
    fn near_valid_frames(code in prop_oneof![0u8..=8, Just(0x1F)], a in 0u8..64, data in any::<[u8; 8]>(), status in any::<bool>()) {
        let f = frame((u16::from(code) << 6) | u16::from(a), &data);
        let ch = if status { Channel::Status } else { Channel::Command };
        if let Ok(t) = Telegram::decode(&f, ch) {
            prop_assert_eq!(t.encode(), f);
        }
    }
}
