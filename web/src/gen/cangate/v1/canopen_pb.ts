// cangate gRPC API: CANopen (CiA 301) master.
//
// The gateway runs a CANopen master on each bus configured with a
// [[canopen]] section: it tracks nodes (boot-up, heartbeat, EMCY), reads and
// writes their object dictionaries over SDO, and sends NMT commands.
//
// Errors (google.rpc status codes):
//   NOT_FOUND           unknown bus, a bus without a CANopen master, or a
//                       node that is neither configured nor ever heard of
//                       (run ScanNetwork first); also SDO abort 0x06020000
//                       (object does not exist) and 0x06090011 (sub-index
//                       does not exist); an object named (`object`) that
//                       the node's EDS does not have (OBJECT_NOT_FOUND).
//   INVALID_ARGUMENT    node id outside 1..=127, a value that does not fit
//                       the object's type, a malformed request; SDO aborts
//                       0x0607xxxx (type/length mismatch); an `object`
//                       name that several objects of the EDS carry (the
//                       message lists them), or `object` given together
//                       with index/subindex.
//   OUT_OF_RANGE        SDO aborts 0x0609003x (value range).
//   FAILED_PRECONDITION SDO aborts 0x0601xxxx (access: read-only,
//                       write-only) and 0x0800002x (device state); the bus
//                       is bus-off or down; the caller already has its
//                       limit of SDO requests queued or running with the
//                       node (per caller - identity, else peer address -
//                       and node: 8 unless [security.limits]
//                       sdo_requests_per_client_and_node says otherwise);
//                       an object named (`object`, ListObjects)
//                       on a node the gateway has no EDS for.
//   ABORTED             any other SDO abort, and protocol violations by the
//                       node (the gateway sent the abort).
//   DEADLINE_EXCEEDED   the node did not answer within the SDO timeout.
//
// The error model (every service of the gateway). Errors follow the
// standard gRPC richer error model: the status code and message as above,
// and in the trailer "grpc-status-details-bin" an encoded
// google.rpc.Status (the same code and message) whose `details` are
// google.protobuf.Any messages. Read it with any gRPC library's
// richer-error support (Python: grpc_status.rpc_status.from_call; Go:
// status.FromError(err).Details(); Rust: tonic_types::StatusExt; Java:
// io.grpc.protobuf.StatusProto.fromThrowable). The details are:
//
// 1. Always first, a google.rpc.ErrorInfo
//    (type.googleapis.com/google.rpc.ErrorInfo):
//    domain    "cangate.v1" on every error of the gateway.
//    reason    what went wrong, UPPER_SNAKE_CASE and stable (match on it,
//              not on the message):
//      <KIND>_NOT_FOUND  a named thing does not exist: BUS_NOT_FOUND,
//                        NODE_NOT_FOUND, RPDO_NOT_FOUND, AXIS_NOT_FOUND,
//                        HANDWHEEL_NOT_FOUND, CANSMC_MASTER_NOT_FOUND,
//                        CANSMC_SLAVE_NOT_FOUND, OBJECT_NOT_FOUND (an
//                        object name a node's EDS does not have),
//                        SIMULATED_DEVICE_NOT_FOUND.
//                        Metadata: "kind" (the thing: "bus", "node",
//                        "axis", "CANsmc master", ...), "name" (the name
//                        asked for, at most its first 64 bytes; for a node
//                        "<id> on bus <bus>" or the id).
//      SDO_ABORT         the node aborted the SDO transfer (code by the
//                        abort's class, see above).
//      SDO_TIMEOUT       the node did not answer in time; the gateway
//                        sent abort 0x05040000 (DEADLINE_EXCEEDED).
//      SDO_PROTOCOL_ERROR the node broke the SDO protocol; the gateway
//                        sent the abort (ABORTED).
//      SDO_CANCELLED     the gateway cancelled the transfer and sent the
//                        abort (ABORTED).
//      SDO_NOT_SENT      the CAN interface gave up a request frame (its
//                        transmit queue stayed full past the interface's
//                        transmit timeout, or it went away): the transfer
//                        ended at once; the gateway sent abort 0x08000000
//                        (UNAVAILABLE: the same call later may succeed).
//                        Metadata of the five SDO reasons: "abort_code"
//                        (8 hex digits, "0x06070013"), "abort_name" (the
//                        CiA 301 text, "unknown abort code" for others),
//                        "node" (decimal node id, "5"), "index" (4 hex
//                        digits, "0x607A"), "subindex" (decimal, "0"),
//                        "aborted_by" ("node" when the node sent the
//                        abort, "gateway" when the gateway did).
//      INVALID_FRAME     a frame of SendFrames is malformed (metadata
//                        "frame": its position in the batch, from 0).
//      BUS_OFF, BUS_DOWN the bus is bus-off or its interface is down
//                        (FAILED_PRECONDITION when nothing was sent,
//                        UNAVAILABLE when part of the batch was).
//      CAN_FD_NOT_SUPPORTED a CAN FD frame for a classic bus.
//      BUS_BUDGET_EXHAUSTED too many client frames already wait for the
//                        bus's client share (UNAVAILABLE).
//      SEND_FAILED       the interface refused a frame (UNAVAILABLE).
//                        Metadata of the five bus reasons: "bus", "sent"
//                        (frames of the batch sent before the failure),
//                        "total" (frames in the batch).
//      AXIS_ACTIVE       the node is the drive of an axis that is enabled
//                        or moving, and the operation (WriteSdo to its
//                        process or program objects, DownloadProgram, LSS)
//                        would disturb it; disable the axis first
//                        (FAILED_PRECONDITION; metadata "axis", "node").
//      AXIS_CONTROLLED_BY_OTHER the axis is held by another lease
//                        (metadata "axis", "holder" as
//                        ControlLease.holder).
//      LEASE_REQUIRED    the command needs a lease and carried none
//                        (metadata "axis").
//      LEASE_UNKNOWN     the lease token is unknown, released or lapsed.
//      LEASE_NOT_COVERING_AXIS the lease does not cover the axis
//                        (metadata "axis").
//      LEASE_OTHER_IDENTITY the lease belongs to another identity
//                        (PERMISSION_DENIED).
//      SHUTTING_DOWN     the gateway is shutting down (UNAVAILABLE;
//                        also how open streams end then).
//      UNAUTHENTICATED   no token or certificate, or an unknown token.
//      PERMISSION_DENIED the caller's role may not call this RPC (the
//                        message names the role needed and the role held).
//      CONCURRENCY_LIMIT, RATE_LIMIT, STREAM_LIMIT, MESSAGE_SIZE_LIMIT,
//      STREAM_QUEUE_LIMIT a per-client limit of [security.limits] was hit
//                        (RESOURCE_EXHAUSTED; nothing ran).
//      FRAME_RATE_LIMIT  the client's raw frame budget of [security.limits]
//                        is spent (RESOURCE_EXHAUSTED; nothing of the batch
//                        was sent; metadata "frames": the frames refused).
//      ATTACH_PROTOCOL   an Attach stream's messages break its protocol
//                        (INVALID_ARGUMENT; see Bus.Attach).
//      NOT_CLASSIFIED    the RPC is not in the gateway's access table
//                        (UNIMPLEMENTED).
//      otherwise         the code's name: INVALID_ARGUMENT,
//                        FAILED_PRECONDITION, PERMISSION_DENIED,
//                        UNAVAILABLE, OUT_OF_RANGE, DEADLINE_EXCEEDED,
//                        ABORTED (the message says what and why).
//    metadata  string keys and values as listed per reason; empty for
//              the others. New keys and reasons may be added; existing
//              ones keep their meaning.
// 2. For the four SDO reasons, a cangate.v1.SdoAbortDetails
//    (type.googleapis.com/cangate.v1.SdoAbortDetails): the abort typed, for
//    clients that generated code from these protos.
//
// SDO errors also carry the abort as text in the response metadata key
// "cangate-sdo-abort" ("0x06070013 data type does not match, length of
// service parameter too low"), for tools that show metadata only.
//
// Statuses that do not come from a service, but from the gateway's
// security layer (UNAUTHENTICATED, a role's PERMISSION_DENIED,
// RESOURCE_EXHAUSTED limits), from the gRPC stack (an undecodable request,
// CANCELLED, a client's own deadline) or that end a stream at shutdown,
// may have no details: clients must accept a status without them.

// @generated by protoc-gen-es v2.13.0 with parameter "target=ts,import_extension=none"
// @generated from file cangate/v1/canopen.proto (package cangate.v1, syntax proto3)
/* eslint-disable */

import type { GenEnum, GenFile, GenMessage, GenService } from "@bufbuild/protobuf/codegenv2";
import { enumDesc, fileDesc, messageDesc, serviceDesc } from "@bufbuild/protobuf/codegenv2";
import type { Message } from "@bufbuild/protobuf";

/**
 * Describes the file cangate/v1/canopen.proto.
 */
export const file_cangate_v1_canopen: GenFile = /*@__PURE__*/
  fileDesc("ChhjYW5nYXRlL3YxL2Nhbm9wZW4ucHJvdG8SCmNhbmdhdGUudjEiugEKBVZhbHVlEiIKBHR5cGUYASABKA4yFC5jYW5nYXRlLnYxLkRhdGFUeXBlEhQKCmJvb2xfdmFsdWUYAiABKAhIABITCglpbnRfdmFsdWUYAyABKBJIABIUCgp1aW50X3ZhbHVlGAQgASgESAASFAoKcmVhbF92YWx1ZRgFIAEoAUgAEhYKDHN0cmluZ192YWx1ZRgGIAEoCUgAEhUKC2J5dGVzX3ZhbHVlGAcgASgMSABCBwoFdmFsdWUiVQoISWRlbnRpdHkSEQoJdmVuZG9yX2lkGAEgASgNEhQKDHByb2R1Y3RfY29kZRgCIAEoDRIQCghyZXZpc2lvbhgDIAEoDRIOCgZzZXJpYWwYBCABKA0iigEKBEVtY3kSDAoEbm9kZRgBIAEoDRIMCgRjb2RlGAIgASgNEhEKCWNvZGVfbmFtZRgDIAEoCRIQCghyZWdpc3RlchgEIAEoDRIVCg1yZWdpc3Rlcl9iaXRzGAUgAygJEhQKDG1hbnVmYWN0dXJlchgGIAEoDBIUCgx0aW1lc3RhbXBfbnMYByABKAQimgQKBE5vZGUSCwoDYnVzGAEgASgJEgoKAmlkGAIgASgNEgwKBG5hbWUYAyABKAkSIwoFc3RhdGUYBCABKA4yFC5jYW5nYXRlLnYxLk5tdFN0YXRlEh0KEGhlYXJ0YmVhdF9hZ2VfbXMYBSABKARIAIgBARIWCg5oZWFydGJlYXRfbG9zdBgGIAEoCBIcChRoZWFydGJlYXRfdGltZW91dF9tcxgHIAEoDRIYCgtkZXZpY2VfdHlwZRgIIAEoDUgBiAEBEhMKC2RldmljZV9uYW1lGAkgASgJEiYKCGlkZW50aXR5GAogASgLMhQuY2FuZ2F0ZS52MS5JZGVudGl0eRImCgxhY3RpdmVfZXJyb3IYCyABKAsyEC5jYW5nYXRlLnYxLkVtY3kSJgoMZW1jeV9oaXN0b3J5GAwgAygLMhAuY2FuZ2F0ZS52MS5FbWN5EhAKCGJvb3RfdXBzGA0gASgEEhIKCmNvbmZpZ3VyZWQYDiABKAgSLgoKbW9uaXRvcmluZxgPIAEoDjIaLmNhbmdhdGUudjEuTGlmZU1vbml0b3JpbmcSFQoNZ3VhcmRfdGltZV9tcxgQIAEoDRIYChBsaWZlX3RpbWVfZmFjdG9yGBEgASgNEh4KFmd1YXJkaW5nX3RvZ2dsZV9lcnJvcnMYEiABKARCEwoRX2hlYXJ0YmVhdF9hZ2VfbXNCDgoMX2RldmljZV90eXBlIh8KEExpc3ROb2Rlc1JlcXVlc3QSCwoDYnVzGAEgASgJIjQKEUxpc3ROb2Rlc1Jlc3BvbnNlEh8KBW5vZGVzGAEgAygLMhAuY2FuZ2F0ZS52MS5Ob2RlIisKDkdldE5vZGVSZXF1ZXN0EgsKA2J1cxgBIAEoCRIMCgRub2RlGAIgASgNImMKDlNlbmRObXRSZXF1ZXN0EgsKA2J1cxgBIAEoCRIMCgRub2RlGAIgASgNEicKB2NvbW1hbmQYAyABKA4yFi5jYW5nYXRlLnYxLk5tdENvbW1hbmQSDQoFZm9yY2UYBCABKAgiEQoPU2VuZE5tdFJlc3BvbnNlIi8KClNkb09wdGlvbnMSEgoKdGltZW91dF9tcxgBIAEoDRINCgVibG9jaxgCIAEoCCKpAQoOUmVhZFNkb1JlcXVlc3QSCwoDYnVzGAEgASgJEgwKBG5vZGUYAiABKA0SDQoFaW5kZXgYAyABKA0SEAoIc3ViaW5kZXgYBCABKA0SIgoEdHlwZRgFIAEoDjIULmNhbmdhdGUudjEuRGF0YVR5cGUSJwoHb3B0aW9ucxgGIAEoCzIWLmNhbmdhdGUudjEuU2RvT3B0aW9ucxIOCgZvYmplY3QYByABKAkiQAoPUmVhZFNkb1Jlc3BvbnNlEgsKA3JhdxgBIAEoDBIgCgV2YWx1ZRgCIAEoCzIRLmNhbmdhdGUudjEuVmFsdWUi0AEKD1dyaXRlU2RvUmVxdWVzdBILCgNidXMYASABKAkSDAoEbm9kZRgCIAEoDRINCgVpbmRleBgDIAEoDRIQCghzdWJpbmRleBgEIAEoDRIiCgV2YWx1ZRgFIAEoCzIRLmNhbmdhdGUudjEuVmFsdWVIABINCgNyYXcYBiABKAxIABInCgdvcHRpb25zGAcgASgLMhYuY2FuZ2F0ZS52MS5TZG9PcHRpb25zEg4KBm9iamVjdBgIIAEoCRINCgVmb3JjZRgJIAEoCEIGCgRkYXRhIiEKEFdyaXRlU2RvUmVzcG9uc2USDQoFYnl0ZXMYASABKA0ihAEKEVNkb1Nlc3Npb25SZXF1ZXN0EgoKAmlkGAEgASgEEioKBHJlYWQYAiABKAsyGi5jYW5nYXRlLnYxLlJlYWRTZG9SZXF1ZXN0SAASLAoFd3JpdGUYAyABKAsyGy5jYW5nYXRlLnYxLldyaXRlU2RvUmVxdWVzdEgAQgkKB3JlcXVlc3QisgEKEFNkb1Nlc3Npb25BbnN3ZXISCgoCaWQYASABKAQSKwoEcmVhZBgCIAEoCzIbLmNhbmdhdGUudjEuUmVhZFNkb1Jlc3BvbnNlSAASLQoFd3JpdGUYAyABKAsyHC5jYW5nYXRlLnYxLldyaXRlU2RvUmVzcG9uc2VIABIsCgVlcnJvchgEIAEoCzIbLmNhbmdhdGUudjEuU2RvU2Vzc2lvbkVycm9ySABCCAoGcmVzdWx0ItoBCg9TZG9TZXNzaW9uRXJyb3ISDAoEY29kZRgBIAEoBRIPCgdtZXNzYWdlGAIgASgJEg4KBnJlYXNvbhgDIAEoCRI7CghtZXRhZGF0YRgEIAMoCzIpLmNhbmdhdGUudjEuU2RvU2Vzc2lvbkVycm9yLk1ldGFkYXRhRW50cnkSKgoFYWJvcnQYBSABKAsyGy5jYW5nYXRlLnYxLlNkb0Fib3J0RGV0YWlscxovCg1NZXRhZGF0YUVudHJ5EgsKA2tleRgBIAEoCRINCgV2YWx1ZRgCIAEoCToCOAEiLwoSTGlzdE9iamVjdHNSZXF1ZXN0EgsKA2J1cxgBIAEoCRIMCgRub2RlGAIgASgNIvsCCgpPYmplY3RJbmZvEg0KBWluZGV4GAEgASgNEhAKCHN1YmluZGV4GAIgASgNEgwKBG5hbWUYAyABKAkSEwoLb2JqZWN0X25hbWUYBCABKAkSEAoIc3ViX25hbWUYBSABKAkSEwoLb2JqZWN0X3R5cGUYBiABKAkSIgoEdHlwZRgHIAEoDjIULmNhbmdhdGUudjEuRGF0YVR5cGUSEQoJdHlwZV9jb2RlGAggASgNEigKBmFjY2VzcxgJIAEoDjIYLmNhbmdhdGUudjEuT2JqZWN0QWNjZXNzEhQKDHBkb19tYXBwYWJsZRgKIAEoCBIoCg1kZWZhdWx0X3ZhbHVlGAsgASgLMhEuY2FuZ2F0ZS52MS5WYWx1ZRIUCgxkZWZhdWx0X3RleHQYDCABKAkSJAoJbG93X2xpbWl0GA0gASgLMhEuY2FuZ2F0ZS52MS5WYWx1ZRIlCgpoaWdoX2xpbWl0GA4gASgLMhEuY2FuZ2F0ZS52MS5WYWx1ZSI+ChNMaXN0T2JqZWN0c1Jlc3BvbnNlEicKB29iamVjdHMYASADKAsyFi5jYW5nYXRlLnYxLk9iamVjdEluZm8iNQoSU2Nhbk5ldHdvcmtSZXF1ZXN0EgsKA2J1cxgBIAEoCRISCgp0aW1lb3V0X21zGAIgASgNIjYKE1NjYW5OZXR3b3JrUmVzcG9uc2USHwoFbm9kZXMYASADKAsyEC5jYW5nYXRlLnYxLk5vZGUiNQoXU3RyZWFtTm9kZUV2ZW50c1JlcXVlc3QSCwoDYnVzGAEgASgJEg0KBW5vZGVzGAIgAygNIoIECglOb2RlRXZlbnQSCwoDYnVzGAEgASgJEgwKBG5vZGUYAiABKA0SFAoMdGltZXN0YW1wX25zGAMgASgEEiUKB2Jvb3RfdXAYBCABKAsyEi5jYW5nYXRlLnYxLkJvb3RVcEgAEjAKDXN0YXRlX2NoYW5nZWQYBSABKAsyFy5jYW5nYXRlLnYxLlN0YXRlQ2hhbmdlSAASMwoOaGVhcnRiZWF0X2xvc3QYBiABKAsyGS5jYW5nYXRlLnYxLkhlYXJ0YmVhdExvc3RIABI9ChNoZWFydGJlYXRfcmVjb3ZlcmVkGAcgASgLMh4uY2FuZ2F0ZS52MS5IZWFydGJlYXRSZWNvdmVyZWRIABIgCgRlbWN5GAggASgLMhAuY2FuZ2F0ZS52MS5FbWN5SAASJgoEbG9zdBgJIAEoCzIWLmNhbmdhdGUudjEuRXZlbnRzTG9zdEgAEjMKDmJvb3RfY29tcGxldGVkGAogASgLMhkuY2FuZ2F0ZS52MS5Cb290Q29tcGxldGVkSAASLQoLYm9vdF9mYWlsZWQYCyABKAsyFi5jYW5nYXRlLnYxLkJvb3RGYWlsZWRIABJAChVndWFyZGluZ190b2dnbGVfZXJyb3IYDCABKAsyHy5jYW5nYXRlLnYxLkd1YXJkaW5nVG9nZ2xlRXJyb3JIAEIHCgVldmVudCJLChNHdWFyZGluZ1RvZ2dsZUVycm9yEgwKBGRhdGEYASABKA0SFwoPZXhwZWN0ZWRfdG9nZ2xlGAIgASgIEg0KBWNvdW50GAMgASgEIg8KDUJvb3RDb21wbGV0ZWQiHAoKQm9vdEZhaWxlZBIOCgZyZWFzb24YASABKAkiLgoQU3RyZWFtUGRvUmVxdWVzdBILCgNidXMYASABKAkSDQoFbm9kZXMYAiADKA0iWwoIUGRvVmFsdWUSDQoFaW5kZXgYASABKA0SEAoIc3ViaW5kZXgYAiABKA0SDAoEbmFtZRgDIAEoCRIgCgV2YWx1ZRgEIAEoCzIRLmNhbmdhdGUudjEuVmFsdWUilQEKClBkb01lc3NhZ2USCwoDYnVzGAEgASgJEgwKBG5vZGUYAiABKA0SCwoDcGRvGAMgASgNEg4KBmNvYl9pZBgEIAEoDRIUCgx0aW1lc3RhbXBfbnMYBSABKAQSJAoGdmFsdWVzGAYgAygLMhQuY2FuZ2F0ZS52MS5QZG9WYWx1ZRITCgtsb3N0X2JlZm9yZRgHIAEoBCJfCg9Xcml0ZVBkb1JlcXVlc3QSCwoDYnVzGAEgASgJEgwKBG5vZGUYAiABKA0SCwoDcGRvGAMgASgNEiQKBnZhbHVlcxgEIAMoCzIULmNhbmdhdGUudjEuUGRvVmFsdWUiIAoQV3JpdGVQZG9SZXNwb25zZRIMCgRkYXRhGAEgASgMIl4KD1Bkb01hcHBlZE9iamVjdBINCgVpbmRleBgBIAEoDRIQCghzdWJpbmRleBgCIAEoDRIMCgRiaXRzGAMgASgNEgwKBG5hbWUYBCABKAkSDgoGb2JqZWN0GAUgASgJIuABChBQZG9Db25maWd1cmF0aW9uEiEKBGtpbmQYASABKA4yEy5jYW5nYXRlLnYxLlBkb0tpbmQSCwoDcGRvGAIgASgNEg4KBmNvYl9pZBgDIAEoDRIPCgdlbmFibGVkGAQgASgIEhkKEXRyYW5zbWlzc2lvbl90eXBlGAUgASgNEhoKEmluaGliaXRfdGltZV8xMDB1cxgGIAEoDRIWCg5ldmVudF90aW1lcl9tcxgHIAEoDRIsCgdtYXBwaW5nGAggAygLMhsuY2FuZ2F0ZS52MS5QZG9NYXBwZWRPYmplY3QiigEKFFJlYWRQZG9Db25maWdSZXF1ZXN0EgsKA2J1cxgBIAEoCRIMCgRub2RlGAIgASgNEiEKBGtpbmQYAyABKA4yEy5jYW5nYXRlLnYxLlBkb0tpbmQSCwoDcGRvGAQgASgNEicKB29wdGlvbnMYBSABKAsyFi5jYW5nYXRlLnYxLlNkb09wdGlvbnMiQwoVUmVhZFBkb0NvbmZpZ1Jlc3BvbnNlEioKBHBkb3MYASADKAsyHC5jYW5nYXRlLnYxLlBkb0NvbmZpZ3VyYXRpb24ihAEKE0NvbmZpZ3VyZVBkb1JlcXVlc3QSCwoDYnVzGAEgASgJEgwKBG5vZGUYAiABKA0SKQoDcGRvGAMgASgLMhwuY2FuZ2F0ZS52MS5QZG9Db25maWd1cmF0aW9uEicKB29wdGlvbnMYBCABKAsyFi5jYW5nYXRlLnYxLlNkb09wdGlvbnMiUQoUQ29uZmlndXJlUGRvUmVzcG9uc2USKQoDcGRvGAEgASgLMhwuY2FuZ2F0ZS52MS5QZG9Db25maWd1cmF0aW9uEg4KBndyaXRlcxgCIAMoCSIdCg5HZXRTeW5jUmVxdWVzdBILCgNidXMYASABKAkimQEKDlNldFN5bmNSZXF1ZXN0EgsKA2J1cxgBIAEoCRIUCgdydW5uaW5nGAIgASgISACIAQESFgoJcGVyaW9kX3VzGAMgASgNSAGIAQESHQoQY291bnRlcl9vdmVyZmxvdxgEIAEoDUgCiAEBQgoKCF9ydW5uaW5nQgwKCl9wZXJpb2RfdXNCEwoRX2NvdW50ZXJfb3ZlcmZsb3cijgEKClN5bmNTdGF0dXMSCwoDYnVzGAEgASgJEg8KB3J1bm5pbmcYAiABKAgSEQoJcGVyaW9kX3VzGAMgASgNEhgKEGNvdW50ZXJfb3ZlcmZsb3cYBCABKA0SDAoEc2VudBgFIAEoBBIPCgdza2lwcGVkGAYgASgEEhYKDnRpbWVfcGVyaW9kX21zGAcgASgNIlUKDlNldFRpbWVSZXF1ZXN0EgsKA2J1cxgBIAEoCRIQCghzZW5kX25vdxgCIAEoCBIWCglwZXJpb2RfbXMYAyABKA1IAIgBAUIMCgpfcGVyaW9kX21zIlAKCVRpbWVPZkRheRIZChFtc19hZnRlcl9taWRuaWdodBgBIAEoDRIXCg9kYXlzX3NpbmNlXzE5ODQYAiABKA0SDwoHdW5peF9tcxgDIAEoBCJOCg9TZXRUaW1lUmVzcG9uc2USIwoEc2VudBgBIAEoCzIVLmNhbmdhdGUudjEuVGltZU9mRGF5EhYKDnRpbWVfcGVyaW9kX21zGAIgASgNIlYKEEV4cG9ydERjZlJlcXVlc3QSCwoDYnVzGAEgASgJEgwKBG5vZGUYAiABKA0SJwoHb3B0aW9ucxgDIAEoCzIWLmNhbmdhdGUudjEuU2RvT3B0aW9ucyJACg1Ta2lwcGVkT2JqZWN0Eg0KBWluZGV4GAEgASgNEhAKCHN1YmluZGV4GAIgASgNEg4KBnJlYXNvbhgDIAEoCSJiChFFeHBvcnREY2ZSZXNwb25zZRILCgNkY2YYASABKAkSFAoMb2JqZWN0c19yZWFkGAIgASgNEioKB3NraXBwZWQYAyADKAsyGS5jYW5nYXRlLnYxLlNraXBwZWRPYmplY3QiCAoGQm9vdFVwIlMKC1N0YXRlQ2hhbmdlEiIKBGZyb20YASABKA4yFC5jYW5nYXRlLnYxLk5tdFN0YXRlEiAKAnRvGAIgASgOMhQuY2FuZ2F0ZS52MS5ObXRTdGF0ZSJTCg1IZWFydGJlYXRMb3N0EhIKCnRpbWVvdXRfbXMYASABKA0SLgoKbW9uaXRvcmluZxgCIAEoDjIaLmNhbmdhdGUudjEuTGlmZU1vbml0b3JpbmcifAoSSGVhcnRiZWF0UmVjb3ZlcmVkEiMKBXN0YXRlGAEgASgOMhQuY2FuZ2F0ZS52MS5ObXRTdGF0ZRIRCglzaWxlbnRfbXMYAiABKAQSLgoKbW9uaXRvcmluZxgDIAEoDjIaLmNhbmdhdGUudjEuTGlmZU1vbml0b3JpbmciGwoKRXZlbnRzTG9zdBINCgVjb3VudBgBIAEoBCJhCg9TZG9BYm9ydERldGFpbHMSDAoEY29kZRgBIAEoDRIMCgRuYW1lGAIgASgJEg0KBWluZGV4GAMgASgNEhAKCHN1YmluZGV4GAQgASgNEhEKCWZyb21fbm9kZRgFIAEoCCImChdMaXN0U2RvVHJhbnNmZXJzUmVxdWVzdBILCgNidXMYASABKAkikQEKC1Nkb1RyYW5zZmVyEgwKBG5vZGUYASABKA0SDQoFaW5kZXgYAiABKA0SEAoIc3ViaW5kZXgYAyABKA0SDgoGdXBsb2FkGAQgASgIEhAKCHByb3RvY29sGAUgASgJEhMKC3RyYW5zZmVycmVkGAYgASgEEhIKBXRvdGFsGAcgASgESACIAQFCCAoGX3RvdGFsIkYKGExpc3RTZG9UcmFuc2ZlcnNSZXNwb25zZRIqCgl0cmFuc2ZlcnMYASADKAsyFy5jYW5nYXRlLnYxLlNkb1RyYW5zZmVyItcBChZEb3dubG9hZFByb2dyYW1SZXF1ZXN0EgsKA2J1cxgBIAEoCRIMCgRub2RlGAIgASgNEg0KBWltYWdlGAMgASgMEg8KB3Byb2dyYW0YBCABKA0SJAoXZXhwZWN0ZWRfaWRlbnRpZmljYXRpb24YBSABKA1IAIgBARINCgVjbGVhchgGIAEoCBIYChBmbGFzaF90aW1lb3V0X21zGAcgASgNEhcKD2Jvb3RfdGltZW91dF9tcxgIIAEoDUIaChhfZXhwZWN0ZWRfaWRlbnRpZmljYXRpb24ingEKF0Rvd25sb2FkUHJvZ3JhbVByb2dyZXNzEiUKBHN0ZXAYASABKA4yFy5jYW5nYXRlLnYxLlByb2dyYW1TdGVwEhIKCmJ5dGVzX2RvbmUYAiABKAQSEwoLYnl0ZXNfdG90YWwYAyABKAQSMwoHb3V0Y29tZRgEIAEoCzIiLmNhbmdhdGUudjEuRG93bmxvYWRQcm9ncmFtT3V0Y29tZSLJAQoWRG93bmxvYWRQcm9ncmFtT3V0Y29tZRIfChJvbGRfaWRlbnRpZmljYXRpb24YASABKA1IAIgBARIaChJuZXdfaWRlbnRpZmljYXRpb24YAiABKA0SDQoFYnl0ZXMYAyABKAQSEwoLZHVyYXRpb25fbXMYBCABKAQSGAoQZGF0YV9kdXJhdGlvbl9tcxgFIAEoBBIdChVkYXRhX2J5dGVzX3Blcl9zZWNvbmQYBiABKAFCFQoTX29sZF9pZGVudGlmaWNhdGlvbiqOAQoITm10U3RhdGUSFQoRTk1UX1NUQVRFX1VOS05PV04QABIaChZOTVRfU1RBVEVfSU5JVElBTElTSU5HEAESFQoRTk1UX1NUQVRFX1NUT1BQRUQQAhIZChVOTVRfU1RBVEVfT1BFUkFUSU9OQUwQAxIdChlOTVRfU1RBVEVfUFJFX09QRVJBVElPTkFMEAQqvgEKCk5tdENvbW1hbmQSGwoXTk1UX0NPTU1BTkRfVU5TUEVDSUZJRUQQABIVChFOTVRfQ09NTUFORF9TVEFSVBABEhQKEE5NVF9DT01NQU5EX1NUT1AQAhIlCiFOTVRfQ09NTUFORF9FTlRFUl9QUkVfT1BFUkFUSU9OQUwQAxIaChZOTVRfQ09NTUFORF9SRVNFVF9OT0RFEAQSIwofTk1UX0NPTU1BTkRfUkVTRVRfQ09NTVVOSUNBVElPThAFKqADCghEYXRhVHlwZRIZChVEQVRBX1RZUEVfVU5TUEVDSUZJRUQQABIVChFEQVRBX1RZUEVfQk9PTEVBThABEhYKEkRBVEFfVFlQRV9JTlRFR0VSOBACEhcKE0RBVEFfVFlQRV9JTlRFR0VSMTYQAxIXChNEQVRBX1RZUEVfSU5URUdFUjMyEAQSFwoTREFUQV9UWVBFX1VOU0lHTkVEOBAFEhgKFERBVEFfVFlQRV9VTlNJR05FRDE2EAYSGAoUREFUQV9UWVBFX1VOU0lHTkVEMzIQBxIUChBEQVRBX1RZUEVfUkVBTDMyEAgSHAoYREFUQV9UWVBFX1ZJU0lCTEVfU1RSSU5HEAkSGgoWREFUQV9UWVBFX09DVEVUX1NUUklORxAKEhwKGERBVEFfVFlQRV9VTklDT0RFX1NUUklORxALEhQKEERBVEFfVFlQRV9ET01BSU4QDxIUChBEQVRBX1RZUEVfUkVBTDY0EBESFwoTREFUQV9UWVBFX0lOVEVHRVI2NBAVEhgKFERBVEFfVFlQRV9VTlNJR05FRDY0EBsqbAoOTGlmZU1vbml0b3JpbmcSGAoUTElGRV9NT05JVE9SSU5HX05PTkUQABIdChlMSUZFX01PTklUT1JJTkdfSEVBUlRCRUFUEAESIQodTElGRV9NT05JVE9SSU5HX05PREVfR1VBUkRJTkcQAiq2AQoMT2JqZWN0QWNjZXNzEh0KGU9CSkVDVF9BQ0NFU1NfVU5TUEVDSUZJRUQQABIUChBPQkpFQ1RfQUNDRVNTX1JPEAESFAoQT0JKRUNUX0FDQ0VTU19XTxACEhQKEE9CSkVDVF9BQ0NFU1NfUlcQAxIVChFPQkpFQ1RfQUNDRVNTX1JXUhAEEhUKEU9CSkVDVF9BQ0NFU1NfUldXEAUSFwoTT0JKRUNUX0FDQ0VTU19DT05TVBAGKkkKB1Bkb0tpbmQSGAoUUERPX0tJTkRfVU5TUEVDSUZJRUQQABIRCg1QRE9fS0lORF9SUERPEAESEQoNUERPX0tJTkRfVFBETxACKr8CCgtQcm9ncmFtU3RlcBIcChhQUk9HUkFNX1NURVBfVU5TUEVDSUZJRUQQABIrCidQUk9HUkFNX1NURVBfUkVBRF9JREVOVElGSUNBVElPTl9CRUZPUkUQARIdChlQUk9HUkFNX1NURVBfU1RPUF9QUk9HUkFNEAISHgoaUFJPR1JBTV9TVEVQX0NMRUFSX1BST0dSQU0QAxIeChpQUk9HUkFNX1NURVBfRE9XTkxPQURfREFUQRAEEhsKF1BST0dSQU1fU1RFUF9XQUlUX0ZMQVNIEAUSHgoaUFJPR1JBTV9TVEVQX1NUQVJUX1BST0dSQU0QBhIdChlQUk9HUkFNX1NURVBfV0FJVF9CT09UX1VQEAcSKgomUFJPR1JBTV9TVEVQX1JFQURfSURFTlRJRklDQVRJT05fQUZURVIQCDKaCwoHQ2Fub3BlbhJICglMaXN0Tm9kZXMSHC5jYW5nYXRlLnYxLkxpc3ROb2Rlc1JlcXVlc3QaHS5jYW5nYXRlLnYxLkxpc3ROb2Rlc1Jlc3BvbnNlEjcKB0dldE5vZGUSGi5jYW5nYXRlLnYxLkdldE5vZGVSZXF1ZXN0GhAuY2FuZ2F0ZS52MS5Ob2RlEkIKB1NlbmRObXQSGi5jYW5nYXRlLnYxLlNlbmRObXRSZXF1ZXN0GhsuY2FuZ2F0ZS52MS5TZW5kTm10UmVzcG9uc2USQgoHUmVhZFNkbxIaLmNhbmdhdGUudjEuUmVhZFNkb1JlcXVlc3QaGy5jYW5nYXRlLnYxLlJlYWRTZG9SZXNwb25zZRJFCghXcml0ZVNkbxIbLmNhbmdhdGUudjEuV3JpdGVTZG9SZXF1ZXN0GhwuY2FuZ2F0ZS52MS5Xcml0ZVNkb1Jlc3BvbnNlEk0KClNkb1Nlc3Npb24SHS5jYW5nYXRlLnYxLlNkb1Nlc3Npb25SZXF1ZXN0GhwuY2FuZ2F0ZS52MS5TZG9TZXNzaW9uQW5zd2VyKAEwARJOCgtMaXN0T2JqZWN0cxIeLmNhbmdhdGUudjEuTGlzdE9iamVjdHNSZXF1ZXN0Gh8uY2FuZ2F0ZS52MS5MaXN0T2JqZWN0c1Jlc3BvbnNlEl0KEExpc3RTZG9UcmFuc2ZlcnMSIy5jYW5nYXRlLnYxLkxpc3RTZG9UcmFuc2ZlcnNSZXF1ZXN0GiQuY2FuZ2F0ZS52MS5MaXN0U2RvVHJhbnNmZXJzUmVzcG9uc2USTgoLU2Nhbk5ldHdvcmsSHi5jYW5nYXRlLnYxLlNjYW5OZXR3b3JrUmVxdWVzdBofLmNhbmdhdGUudjEuU2Nhbk5ldHdvcmtSZXNwb25zZRJQChBTdHJlYW1Ob2RlRXZlbnRzEiMuY2FuZ2F0ZS52MS5TdHJlYW1Ob2RlRXZlbnRzUmVxdWVzdBoVLmNhbmdhdGUudjEuTm9kZUV2ZW50MAESQwoJU3RyZWFtUGRvEhwuY2FuZ2F0ZS52MS5TdHJlYW1QZG9SZXF1ZXN0GhYuY2FuZ2F0ZS52MS5QZG9NZXNzYWdlMAESRQoIV3JpdGVQZG8SGy5jYW5nYXRlLnYxLldyaXRlUGRvUmVxdWVzdBocLmNhbmdhdGUudjEuV3JpdGVQZG9SZXNwb25zZRJUCg1SZWFkUGRvQ29uZmlnEiAuY2FuZ2F0ZS52MS5SZWFkUGRvQ29uZmlnUmVxdWVzdBohLmNhbmdhdGUudjEuUmVhZFBkb0NvbmZpZ1Jlc3BvbnNlElEKDENvbmZpZ3VyZVBkbxIfLmNhbmdhdGUudjEuQ29uZmlndXJlUGRvUmVxdWVzdBogLmNhbmdhdGUudjEuQ29uZmlndXJlUGRvUmVzcG9uc2USPQoHR2V0U3luYxIaLmNhbmdhdGUudjEuR2V0U3luY1JlcXVlc3QaFi5jYW5nYXRlLnYxLlN5bmNTdGF0dXMSPQoHU2V0U3luYxIaLmNhbmdhdGUudjEuU2V0U3luY1JlcXVlc3QaFi5jYW5nYXRlLnYxLlN5bmNTdGF0dXMSQgoHU2V0VGltZRIaLmNhbmdhdGUudjEuU2V0VGltZVJlcXVlc3QaGy5jYW5nYXRlLnYxLlNldFRpbWVSZXNwb25zZRJICglFeHBvcnREY2YSHC5jYW5nYXRlLnYxLkV4cG9ydERjZlJlcXVlc3QaHS5jYW5nYXRlLnYxLkV4cG9ydERjZlJlc3BvbnNlElwKD0Rvd25sb2FkUHJvZ3JhbRIiLmNhbmdhdGUudjEuRG93bmxvYWRQcm9ncmFtUmVxdWVzdBojLmNhbmdhdGUudjEuRG93bmxvYWRQcm9ncmFtUHJvZ3Jlc3MwAWIGcHJvdG8z");

/**
 * A typed value. Integers of every width travel as int64/uint64; the
 * DataType says how they are encoded on the bus.
 *
 * @generated from message cangate.v1.Value
 */
export type Value = Message<"cangate.v1.Value"> & {
  /**
   * The CiA 301 type.
   *
   * @generated from field: cangate.v1.DataType type = 1;
   */
  type: DataType;

  /**
   * The value.
   *
   * @generated from oneof cangate.v1.Value.value
   */
  value: {
    /**
     * BOOLEAN.
     *
     * @generated from field: bool bool_value = 2;
     */
    value: boolean;
    case: "boolValue";
  } | {
    /**
     * INTEGER8..INTEGER64.
     *
     * @generated from field: sint64 int_value = 3;
     */
    value: bigint;
    case: "intValue";
  } | {
    /**
     * UNSIGNED8..UNSIGNED64.
     *
     * @generated from field: uint64 uint_value = 4;
     */
    value: bigint;
    case: "uintValue";
  } | {
    /**
     * REAL32, REAL64.
     *
     * @generated from field: double real_value = 5;
     */
    value: number;
    case: "realValue";
  } | {
    /**
     * VISIBLE_STRING, UNICODE_STRING.
     *
     * @generated from field: string string_value = 6;
     */
    value: string;
    case: "stringValue";
  } | {
    /**
     * OCTET_STRING, DOMAIN.
     *
     * @generated from field: bytes bytes_value = 7;
     */
    value: Uint8Array;
    case: "bytesValue";
  } | { case: undefined; value?: undefined };
};

/**
 * Describes the message cangate.v1.Value.
 * Use `create(ValueSchema)` to create a new message.
 */
export const ValueSchema: GenMessage<Value> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 0);

/**
 * The device identity (object 0x1018).
 *
 * @generated from message cangate.v1.Identity
 */
export type Identity = Message<"cangate.v1.Identity"> & {
  /**
   * 0x1018:01 vendor id.
   *
   * @generated from field: uint32 vendor_id = 1;
   */
  vendorId: number;

  /**
   * 0x1018:02 product code.
   *
   * @generated from field: uint32 product_code = 2;
   */
  productCode: number;

  /**
   * 0x1018:03 revision number.
   *
   * @generated from field: uint32 revision = 3;
   */
  revision: number;

  /**
   * 0x1018:04 serial number.
   *
   * @generated from field: uint32 serial = 4;
   */
  serial: number;
};

/**
 * Describes the message cangate.v1.Identity.
 * Use `create(IdentitySchema)` to create a new message.
 */
export const IdentitySchema: GenMessage<Identity> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 1);

/**
 * An emergency message.
 *
 * @generated from message cangate.v1.Emcy
 */
export type Emcy = Message<"cangate.v1.Emcy"> & {
  /**
   * Node id.
   *
   * @generated from field: uint32 node = 1;
   */
  node: number;

  /**
   * Error code (0x0000 = error reset / no error).
   *
   * @generated from field: uint32 code = 2;
   */
  code: number;

  /**
   * Name of the error code (CiA 301 / CiA 402 tables).
   *
   * @generated from field: string code_name = 3;
   */
  codeName: string;

  /**
   * Error register (object 0x1001).
   *
   * @generated from field: uint32 register = 4;
   */
  register: number;

  /**
   * Names of the bits set in the error register.
   *
   * @generated from field: repeated string register_bits = 5;
   */
  registerBits: string[];

  /**
   * Manufacturer-specific bytes (5).
   *
   * @generated from field: bytes manufacturer = 6;
   */
  manufacturer: Uint8Array;

  /**
   * Receive time in nanoseconds since the UNIX epoch.
   *
   * @generated from field: uint64 timestamp_ns = 7;
   */
  timestampNs: bigint;
};

/**
 * Describes the message cangate.v1.Emcy.
 * Use `create(EmcySchema)` to create a new message.
 */
export const EmcySchema: GenMessage<Emcy> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 2);

/**
 * A node as the master knows it.
 *
 * @generated from message cangate.v1.Node
 */
export type Node = Message<"cangate.v1.Node"> & {
  /**
   * Bus name.
   *
   * @generated from field: string bus = 1;
   */
  bus: string;

  /**
   * Node id (1..=127).
   *
   * @generated from field: uint32 id = 2;
   */
  id: number;

  /**
   * Configured name, if any.
   *
   * @generated from field: string name = 3;
   */
  name: string;

  /**
   * Last NMT state reported by heartbeat / boot-up (a guarded node: by its
   * guarding answers). A node with neither: the state its boot procedure
   * found (a node guarding answer) or left it in (commanded).
   *
   * @generated from field: cangate.v1.NmtState state = 4;
   */
  state: NmtState;

  /**
   * Milliseconds since the last heartbeat (absent if never heard); for a
   * guarded node since its last valid guarding answer.
   *
   * @generated from field: optional uint64 heartbeat_age_ms = 5;
   */
  heartbeatAgeMs?: bigint | undefined;

  /**
   * The heartbeat is monitored and overdue, or the guarded node answered
   * no request within its life time.
   *
   * @generated from field: bool heartbeat_lost = 6;
   */
  heartbeatLost: boolean;

  /**
   * Consumer heartbeat timeout in ms (0 = not monitored).
   *
   * @generated from field: uint32 heartbeat_timeout_ms = 7;
   */
  heartbeatTimeoutMs: number;

  /**
   * Device type (0x1000) if read (by the boot procedure of a configured
   * node, or by a scan).
   *
   * @generated from field: optional uint32 device_type = 8;
   */
  deviceType?: number | undefined;

  /**
   * Manufacturer device name (0x1008) if read.
   *
   * @generated from field: string device_name = 9;
   */
  deviceName: string;

  /**
   * Identity (0x1018) if read (by the boot procedure or a scan); entries
   * the node does not have are 0.
   *
   * @generated from field: cangate.v1.Identity identity = 10;
   */
  identity?: Identity | undefined;

  /**
   * The active error (last EMCY not followed by a reset), if any.
   *
   * @generated from field: cangate.v1.Emcy active_error = 11;
   */
  activeError?: Emcy | undefined;

  /**
   * Recent EMCY messages, oldest first (at most 32).
   *
   * @generated from field: repeated cangate.v1.Emcy emcy_history = 12;
   */
  emcyHistory: Emcy[];

  /**
   * Boot-up messages received.
   *
   * @generated from field: uint64 boot_ups = 13;
   */
  bootUps: bigint;

  /**
   * The node is configured (as opposed to only discovered).
   *
   * @generated from field: bool configured = 14;
   */
  configured: boolean;

  /**
   * How the master watches the node: heartbeat consumer or node guarding
   * (a node uses one or the other, CiA 301). For a guarded node
   * heartbeat_age_ms and heartbeat_lost describe its guarding answers
   * (time since the last valid answer; life time run out).
   *
   * @generated from field: cangate.v1.LifeMonitoring monitoring = 15;
   */
  monitoring: LifeMonitoring;

  /**
   * Node guarding: guard time in ms, the request period (0 = not guarded).
   *
   * @generated from field: uint32 guard_time_ms = 16;
   */
  guardTimeMs: number;

  /**
   * Node guarding: life time factor (lost after this many unanswered
   * requests in a row).
   *
   * @generated from field: uint32 life_time_factor = 17;
   */
  lifeTimeFactor: number;

  /**
   * Node guarding: answers with a wrong toggle bit so far.
   *
   * @generated from field: uint64 guarding_toggle_errors = 18;
   */
  guardingToggleErrors: bigint;
};

/**
 * Describes the message cangate.v1.Node.
 * Use `create(NodeSchema)` to create a new message.
 */
export const NodeSchema: GenMessage<Node> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 3);

/**
 * ListNodes request.
 *
 * @generated from message cangate.v1.ListNodesRequest
 */
export type ListNodesRequest = Message<"cangate.v1.ListNodesRequest"> & {
  /**
   * Bus name; empty for every CANopen bus.
   *
   * @generated from field: string bus = 1;
   */
  bus: string;
};

/**
 * Describes the message cangate.v1.ListNodesRequest.
 * Use `create(ListNodesRequestSchema)` to create a new message.
 */
export const ListNodesRequestSchema: GenMessage<ListNodesRequest> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 4);

/**
 * ListNodes response.
 *
 * @generated from message cangate.v1.ListNodesResponse
 */
export type ListNodesResponse = Message<"cangate.v1.ListNodesResponse"> & {
  /**
   * Nodes sorted by bus and id.
   *
   * @generated from field: repeated cangate.v1.Node nodes = 1;
   */
  nodes: Node[];
};

/**
 * Describes the message cangate.v1.ListNodesResponse.
 * Use `create(ListNodesResponseSchema)` to create a new message.
 */
export const ListNodesResponseSchema: GenMessage<ListNodesResponse> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 5);

/**
 * GetNode request.
 *
 * @generated from message cangate.v1.GetNodeRequest
 */
export type GetNodeRequest = Message<"cangate.v1.GetNodeRequest"> & {
  /**
   * Bus name.
   *
   * @generated from field: string bus = 1;
   */
  bus: string;

  /**
   * Node id.
   *
   * @generated from field: uint32 node = 2;
   */
  node: number;
};

/**
 * Describes the message cangate.v1.GetNodeRequest.
 * Use `create(GetNodeRequestSchema)` to create a new message.
 */
export const GetNodeRequestSchema: GenMessage<GetNodeRequest> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 6);

/**
 * SendNmt request.
 *
 * @generated from message cangate.v1.SendNmtRequest
 */
export type SendNmtRequest = Message<"cangate.v1.SendNmtRequest"> & {
  /**
   * Bus name.
   *
   * @generated from field: string bus = 1;
   */
  bus: string;

  /**
   * Node id, or 0 for all nodes (broadcast).
   *
   * @generated from field: uint32 node = 2;
   */
  node: number;

  /**
   * The command.
   *
   * @generated from field: cangate.v1.NmtCommand command = 3;
   */
  command: NmtCommand;

  /**
   * Send it even to the drive of an enabled or moving axis. Without it,
   * STOP, ENTER_PRE_OPERATIONAL, RESET_NODE and RESET_COMMUNICATION to
   * such a drive (or to all nodes while one is active) are refused with
   * FAILED_PRECONDITION, reason AXIS_ACTIVE: each takes the drive out of
   * operational, so it stops receiving its set-points and its axis
   * faults. START is never refused.
   *
   * @generated from field: bool force = 4;
   */
  force: boolean;
};

/**
 * Describes the message cangate.v1.SendNmtRequest.
 * Use `create(SendNmtRequestSchema)` to create a new message.
 */
export const SendNmtRequestSchema: GenMessage<SendNmtRequest> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 7);

/**
 * SendNmt response.
 *
 * @generated from message cangate.v1.SendNmtResponse
 */
export type SendNmtResponse = Message<"cangate.v1.SendNmtResponse"> & {
};

/**
 * Describes the message cangate.v1.SendNmtResponse.
 * Use `create(SendNmtResponseSchema)` to create a new message.
 */
export const SendNmtResponseSchema: GenMessage<SendNmtResponse> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 8);

/**
 * SDO transfer options common to reads and writes.
 *
 * A node's SDO channel carries one transfer at a time. The gateway's own
 * transfers (boot procedure, axis process data by SDO) go before those of
 * API calls; while one of them waits, a running API transfer gets at most
 * the bus default timeout for each answer of the node.
 *
 * @generated from message cangate.v1.SdoOptions
 */
export type SdoOptions = Message<"cangate.v1.SdoOptions"> & {
  /**
   * Timeout for each answer of the node in ms (0 = the bus default,
   * normally 500 ms; at most 60000, more is INVALID_ARGUMENT).
   *
   * @generated from field: uint32 timeout_ms = 1;
   */
  timeoutMs: number;

  /**
   * Use SDO block transfer (falls back to segmented if the node refuses).
   *
   * @generated from field: bool block = 2;
   */
  block: boolean;
};

/**
 * Describes the message cangate.v1.SdoOptions.
 * Use `create(SdoOptionsSchema)` to create a new message.
 */
export const SdoOptionsSchema: GenMessage<SdoOptions> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 9);

/**
 * ReadSdo request.
 *
 * @generated from message cangate.v1.ReadSdoRequest
 */
export type ReadSdoRequest = Message<"cangate.v1.ReadSdoRequest"> & {
  /**
   * Bus name.
   *
   * @generated from field: string bus = 1;
   */
  bus: string;

  /**
   * Node id.
   *
   * @generated from field: uint32 node = 2;
   */
  node: number;

  /**
   * Object index (0 when `object` is given).
   *
   * @generated from field: uint32 index = 3;
   */
  index: number;

  /**
   * Sub-index (0 when `object` is given).
   *
   * @generated from field: uint32 subindex = 4;
   */
  subindex: number;

  /**
   * Decode the bytes as this type (otherwise the node's EDS type is used
   * when known; else only raw bytes are returned).
   *
   * @generated from field: cangate.v1.DataType type = 5;
   */
  type: DataType;

  /**
   * Options.
   *
   * @generated from field: cangate.v1.SdoOptions options = 6;
   */
  options?: SdoOptions | undefined;

  /**
   * The object as a person names it, resolved with the node's EDS instead
   * of index/subindex (which must then be 0): a ParameterName ("Producer
   * heartbeat time"; a sub-object's alone when only one object has it),
   * "object.sub" ("Identity object.Serial number", "0x1018.Vendor-ID") or
   * an address ("0x1018:04", "1017"). Names match case-insensitively,
   * with "_", "-" and spaces alike; as ObjectInfo.name shows them they
   * always work. Empty: index/subindex. See the errors at the top.
   *
   * @generated from field: string object = 7;
   */
  object: string;
};

/**
 * Describes the message cangate.v1.ReadSdoRequest.
 * Use `create(ReadSdoRequestSchema)` to create a new message.
 */
export const ReadSdoRequestSchema: GenMessage<ReadSdoRequest> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 10);

/**
 * ReadSdo response.
 *
 * @generated from message cangate.v1.ReadSdoResponse
 */
export type ReadSdoResponse = Message<"cangate.v1.ReadSdoResponse"> & {
  /**
   * The bytes read.
   *
   * @generated from field: bytes raw = 1;
   */
  raw: Uint8Array;

  /**
   * The decoded value, when a type was given or known.
   *
   * @generated from field: cangate.v1.Value value = 2;
   */
  value?: Value | undefined;
};

/**
 * Describes the message cangate.v1.ReadSdoResponse.
 * Use `create(ReadSdoResponseSchema)` to create a new message.
 */
export const ReadSdoResponseSchema: GenMessage<ReadSdoResponse> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 11);

/**
 * WriteSdo request.
 *
 * @generated from message cangate.v1.WriteSdoRequest
 */
export type WriteSdoRequest = Message<"cangate.v1.WriteSdoRequest"> & {
  /**
   * Bus name.
   *
   * @generated from field: string bus = 1;
   */
  bus: string;

  /**
   * Node id.
   *
   * @generated from field: uint32 node = 2;
   */
  node: number;

  /**
   * Object index (0 when `object` is given).
   *
   * @generated from field: uint32 index = 3;
   */
  index: number;

  /**
   * Sub-index (0 when `object` is given).
   *
   * @generated from field: uint32 subindex = 4;
   */
  subindex: number;

  /**
   * What to write: a typed value (encoded per its type; integers are range
   * checked) or raw bytes sent as they are.
   *
   * @generated from oneof cangate.v1.WriteSdoRequest.data
   */
  data: {
    /**
     * A typed value. With type DATA_TYPE_UNSPECIFIED the object's type in
     * the node's EDS is used (INVALID_ARGUMENT when the EDS does not have
     * the object): numbers, booleans and bytes are converted to it, and a
     * string_value for a non-string type is parsed as a person types it
     * ("100", "0x64", "-5", "true", "1.5", hex bytes "DE AD").
     *
     * @generated from field: cangate.v1.Value value = 5;
     */
    value: Value;
    case: "value";
  } | {
    /**
     * Raw bytes. More bytes than a fixed-size object of the node's EDS
     * holds is INVALID_ARGUMENT, refused before anything is sent; objects
     * the EDS does not describe and strings/domains take any size.
     *
     * @generated from field: bytes raw = 6;
     */
    value: Uint8Array;
    case: "raw";
  } | { case: undefined; value?: undefined };

  /**
   * Options.
   *
   * @generated from field: cangate.v1.SdoOptions options = 7;
   */
  options?: SdoOptions | undefined;

  /**
   * The object by name instead of index/subindex, as in
   * ReadSdoRequest.object.
   *
   * @generated from field: string object = 8;
   */
  object: string;

  /**
   * Write even when the node is the drive of an enabled or moving axis.
   * Without it, a write to such a drive's CiA 402 process objects
   * (0x6040 controlword, 0x6060 mode of operation, 0x607A target position,
   * 0x60FF target velocity, 0x6071 target torque) or program objects
   * (0x1F50 program data, 0x1F51 program control) is refused before
   * anything is sent: FAILED_PRECONDITION, reason AXIS_ACTIVE, metadata
   * "axis" and "node", the message naming the axis. Only an engineer may
   * call WriteSdo, so only an engineer can force; the axis does not know
   * what the forced write did to its drive.
   *
   * @generated from field: bool force = 9;
   */
  force: boolean;
};

/**
 * Describes the message cangate.v1.WriteSdoRequest.
 * Use `create(WriteSdoRequestSchema)` to create a new message.
 */
export const WriteSdoRequestSchema: GenMessage<WriteSdoRequest> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 12);

/**
 * WriteSdo response.
 *
 * @generated from message cangate.v1.WriteSdoResponse
 */
export type WriteSdoResponse = Message<"cangate.v1.WriteSdoResponse"> & {
  /**
   * Bytes written.
   *
   * @generated from field: uint32 bytes = 1;
   */
  bytes: number;
};

/**
 * Describes the message cangate.v1.WriteSdoResponse.
 * Use `create(WriteSdoResponseSchema)` to create a new message.
 */
export const WriteSdoResponseSchema: GenMessage<WriteSdoResponse> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 13);

/**
 * One request of an SdoSession.
 *
 * @generated from message cangate.v1.SdoSessionRequest
 */
export type SdoSessionRequest = Message<"cangate.v1.SdoSessionRequest"> & {
  /**
   * Chosen by the client, returned in the answer (the gateway does not
   * check that ids are unique).
   *
   * @generated from field: uint64 id = 1;
   */
  id: bigint;

  /**
   * The transfer.
   *
   * @generated from oneof cangate.v1.SdoSessionRequest.request
   */
  request: {
    /**
     * A read, as ReadSdo.
     *
     * @generated from field: cangate.v1.ReadSdoRequest read = 2;
     */
    value: ReadSdoRequest;
    case: "read";
  } | {
    /**
     * A write, as WriteSdo.
     *
     * @generated from field: cangate.v1.WriteSdoRequest write = 3;
     */
    value: WriteSdoRequest;
    case: "write";
  } | { case: undefined; value?: undefined };
};

/**
 * Describes the message cangate.v1.SdoSessionRequest.
 * Use `create(SdoSessionRequestSchema)` to create a new message.
 */
export const SdoSessionRequestSchema: GenMessage<SdoSessionRequest> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 14);

/**
 * One answer of an SdoSession.
 *
 * @generated from message cangate.v1.SdoSessionAnswer
 */
export type SdoSessionAnswer = Message<"cangate.v1.SdoSessionAnswer"> & {
  /**
   * The id of the request answered.
   *
   * @generated from field: uint64 id = 1;
   */
  id: bigint;

  /**
   * The result.
   *
   * @generated from oneof cangate.v1.SdoSessionAnswer.result
   */
  result: {
    /**
     * A read's result, as ReadSdo's response.
     *
     * @generated from field: cangate.v1.ReadSdoResponse read = 2;
     */
    value: ReadSdoResponse;
    case: "read";
  } | {
    /**
     * A write's result, as WriteSdo's response.
     *
     * @generated from field: cangate.v1.WriteSdoResponse write = 3;
     */
    value: WriteSdoResponse;
    case: "write";
  } | {
    /**
     * The request failed: the error ReadSdo/WriteSdo would have ended
     * with. A request that is neither read nor write is INVALID_ARGUMENT.
     *
     * @generated from field: cangate.v1.SdoSessionError error = 4;
     */
    value: SdoSessionError;
    case: "error";
  } | { case: undefined; value?: undefined };
};

/**
 * Describes the message cangate.v1.SdoSessionAnswer.
 * Use `create(SdoSessionAnswerSchema)` to create a new message.
 */
export const SdoSessionAnswerSchema: GenMessage<SdoSessionAnswer> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 15);

/**
 * The error of one request of an SdoSession: the status ReadSdo/WriteSdo
 * would have returned, with its ErrorInfo and SdoAbortDetails (see "The
 * error model" at the top of this file).
 *
 * @generated from message cangate.v1.SdoSessionError
 */
export type SdoSessionError = Message<"cangate.v1.SdoSessionError"> & {
  /**
   * The gRPC status code (google.rpc.Code: 5 NOT_FOUND, 9
   * FAILED_PRECONDITION, ...).
   *
   * @generated from field: int32 code = 1;
   */
  code: number;

  /**
   * For people.
   *
   * @generated from field: string message = 2;
   */
  message: string;

  /**
   * The ErrorInfo reason (SDO_ABORT, NODE_NOT_FOUND, AXIS_ACTIVE,
   * PERMISSION_DENIED, ...).
   *
   * @generated from field: string reason = 3;
   */
  reason: string;

  /**
   * The ErrorInfo metadata, as listed per reason at the top of this file.
   *
   * @generated from field: map<string, string> metadata = 4;
   */
  metadata: { [key: string]: string };

  /**
   * The abort of an error caused by an SDO transfer (reasons SDO_ABORT,
   * SDO_TIMEOUT, SDO_PROTOCOL_ERROR, SDO_CANCELLED, SDO_NOT_SENT); unset
   * for the others.
   *
   * @generated from field: cangate.v1.SdoAbortDetails abort = 5;
   */
  abort?: SdoAbortDetails | undefined;
};

/**
 * Describes the message cangate.v1.SdoSessionError.
 * Use `create(SdoSessionErrorSchema)` to create a new message.
 */
export const SdoSessionErrorSchema: GenMessage<SdoSessionError> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 16);

/**
 * ListObjects request.
 *
 * @generated from message cangate.v1.ListObjectsRequest
 */
export type ListObjectsRequest = Message<"cangate.v1.ListObjectsRequest"> & {
  /**
   * Bus name.
   *
   * @generated from field: string bus = 1;
   */
  bus: string;

  /**
   * Node id.
   *
   * @generated from field: uint32 node = 2;
   */
  node: number;
};

/**
 * Describes the message cangate.v1.ListObjectsRequest.
 * Use `create(ListObjectsRequestSchema)` to create a new message.
 */
export const ListObjectsRequestSchema: GenMessage<ListObjectsRequest> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 17);

/**
 * One sub-object of a node's object dictionary (from its EDS/DCF).
 *
 * @generated from message cangate.v1.ObjectInfo
 */
export type ObjectInfo = Message<"cangate.v1.ObjectInfo"> & {
  /**
   * Object index.
   *
   * @generated from field: uint32 index = 1;
   */
  index: number;

  /**
   * Sub-index (0 for a VAR).
   *
   * @generated from field: uint32 subindex = 2;
   */
  subindex: number;

  /**
   * The name to give ReadSdoRequest.object / WriteSdoRequest.object: the
   * ParameterName for a single-value object ("Producer heartbeat time"),
   * "object.sub" for a sub-object of an ARRAY or RECORD ("Identity
   * object.Vendor-ID").
   *
   * @generated from field: string name = 3;
   */
  name: string;

  /**
   * The object's ParameterName ("Identity object").
   *
   * @generated from field: string object_name = 4;
   */
  objectName: string;

  /**
   * The sub-object's ParameterName ("Vendor-ID"; for a VAR the same as
   * object_name).
   *
   * @generated from field: string sub_name = 5;
   */
  subName: string;

  /**
   * The object's code: "VAR", "ARRAY", "RECORD", "DOMAIN", "DEFTYPE",
   * "DEFSTRUCT" or "NULL".
   *
   * @generated from field: string object_type = 6;
   */
  objectType: string;

  /**
   * Data type (DATA_TYPE_UNSPECIFIED for a type this enum does not name;
   * type_code has it).
   *
   * @generated from field: cangate.v1.DataType type = 7;
   */
  type: DataType;

  /**
   * The CiA 301 data type code (0x0007 for UNSIGNED32).
   *
   * @generated from field: uint32 type_code = 8;
   */
  typeCode: number;

  /**
   * Access rights.
   *
   * @generated from field: cangate.v1.ObjectAccess access = 9;
   */
  access: ObjectAccess;

  /**
   * May be mapped into a PDO.
   *
   * @generated from field: bool pdo_mappable = 10;
   */
  pdoMappable: boolean;

  /**
   * The initial value on this node (a DCF's ParameterValue, else the
   * DefaultValue, with $NODEID resolved), when the EDS gives one and its
   * type is one DataType names.
   *
   * @generated from field: cangate.v1.Value default_value = 11;
   */
  defaultValue?: Value | undefined;

  /**
   * The default as the EDS writes it ("$NODEID+0x180", "1000"); empty
   * when there is none.
   *
   * @generated from field: string default_text = 12;
   */
  defaultText: string;

  /**
   * LowLimit, when given.
   *
   * @generated from field: cangate.v1.Value low_limit = 13;
   */
  lowLimit?: Value | undefined;

  /**
   * HighLimit, when given.
   *
   * @generated from field: cangate.v1.Value high_limit = 14;
   */
  highLimit?: Value | undefined;
};

/**
 * Describes the message cangate.v1.ObjectInfo.
 * Use `create(ObjectInfoSchema)` to create a new message.
 */
export const ObjectInfoSchema: GenMessage<ObjectInfo> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 18);

/**
 * ListObjects response.
 *
 * @generated from message cangate.v1.ListObjectsResponse
 */
export type ListObjectsResponse = Message<"cangate.v1.ListObjectsResponse"> & {
  /**
   * Every sub-object, by index and sub-index.
   *
   * @generated from field: repeated cangate.v1.ObjectInfo objects = 1;
   */
  objects: ObjectInfo[];
};

/**
 * Describes the message cangate.v1.ListObjectsResponse.
 * Use `create(ListObjectsResponseSchema)` to create a new message.
 */
export const ListObjectsResponseSchema: GenMessage<ListObjectsResponse> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 19);

/**
 * ScanNetwork request.
 *
 * @generated from message cangate.v1.ScanNetworkRequest
 */
export type ScanNetworkRequest = Message<"cangate.v1.ScanNetworkRequest"> & {
  /**
   * Bus name.
   *
   * @generated from field: string bus = 1;
   */
  bus: string;

  /**
   * Per-node answer timeout in ms (0 = 100; at most 10000, more is
   * INVALID_ARGUMENT).
   *
   * @generated from field: uint32 timeout_ms = 2;
   */
  timeoutMs: number;
};

/**
 * Describes the message cangate.v1.ScanNetworkRequest.
 * Use `create(ScanNetworkRequestSchema)` to create a new message.
 */
export const ScanNetworkRequestSchema: GenMessage<ScanNetworkRequest> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 20);

/**
 * ScanNetwork response.
 *
 * @generated from message cangate.v1.ScanNetworkResponse
 */
export type ScanNetworkResponse = Message<"cangate.v1.ScanNetworkResponse"> & {
  /**
   * The nodes that answered, by id.
   *
   * @generated from field: repeated cangate.v1.Node nodes = 1;
   */
  nodes: Node[];
};

/**
 * Describes the message cangate.v1.ScanNetworkResponse.
 * Use `create(ScanNetworkResponseSchema)` to create a new message.
 */
export const ScanNetworkResponseSchema: GenMessage<ScanNetworkResponse> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 21);

/**
 * StreamNodeEvents request.
 *
 * @generated from message cangate.v1.StreamNodeEventsRequest
 */
export type StreamNodeEventsRequest = Message<"cangate.v1.StreamNodeEventsRequest"> & {
  /**
   * Bus name; empty for every CANopen bus.
   *
   * @generated from field: string bus = 1;
   */
  bus: string;

  /**
   * Only these node ids, each 1..=127 (empty: all).
   *
   * @generated from field: repeated uint32 nodes = 2;
   */
  nodes: number[];
};

/**
 * Describes the message cangate.v1.StreamNodeEventsRequest.
 * Use `create(StreamNodeEventsRequestSchema)` to create a new message.
 */
export const StreamNodeEventsRequestSchema: GenMessage<StreamNodeEventsRequest> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 22);

/**
 * Something that happened to a node.
 *
 * @generated from message cangate.v1.NodeEvent
 */
export type NodeEvent = Message<"cangate.v1.NodeEvent"> & {
  /**
   * Bus name.
   *
   * @generated from field: string bus = 1;
   */
  bus: string;

  /**
   * Node id.
   *
   * @generated from field: uint32 node = 2;
   */
  node: number;

  /**
   * When the gateway saw it, nanoseconds since the UNIX epoch.
   *
   * @generated from field: uint64 timestamp_ns = 3;
   */
  timestampNs: bigint;

  /**
   * What happened.
   *
   * @generated from oneof cangate.v1.NodeEvent.event
   */
  event: {
    /**
     * A boot-up message.
     *
     * @generated from field: cangate.v1.BootUp boot_up = 4;
     */
    value: BootUp;
    case: "bootUp";
  } | {
    /**
     * The NMT state changed.
     *
     * @generated from field: cangate.v1.StateChange state_changed = 5;
     */
    value: StateChange;
    case: "stateChanged";
  } | {
    /**
     * The heartbeat is overdue, or (monitoring = NODE_GUARDING) the node
     * answered no guarding request within its life time.
     *
     * @generated from field: cangate.v1.HeartbeatLost heartbeat_lost = 6;
     */
    value: HeartbeatLost;
    case: "heartbeatLost";
  } | {
    /**
     * The heartbeat came back, or the node answered guarding again.
     *
     * @generated from field: cangate.v1.HeartbeatRecovered heartbeat_recovered = 7;
     */
    value: HeartbeatRecovered;
    case: "heartbeatRecovered";
  } | {
    /**
     * An EMCY (error or reset).
     *
     * @generated from field: cangate.v1.Emcy emcy = 8;
     */
    value: Emcy;
    case: "emcy";
  } | {
    /**
     * This client missed events because it read too slowly.
     *
     * @generated from field: cangate.v1.EventsLost lost = 9;
     */
    value: EventsLost;
    case: "lost";
  } | {
    /**
     * The boot procedure checked, configured and NMT-started the node.
     *
     * @generated from field: cangate.v1.BootCompleted boot_completed = 10;
     */
    value: BootCompleted;
    case: "bootCompleted";
  } | {
    /**
     * The boot procedure failed; the node was not started.
     *
     * @generated from field: cangate.v1.BootFailed boot_failed = 11;
     */
    value: BootFailed;
    case: "bootFailed";
  } | {
    /**
     * A node guarding answer with the wrong toggle bit (not accepted as a
     * sign of life).
     *
     * @generated from field: cangate.v1.GuardingToggleError guarding_toggle_error = 12;
     */
    value: GuardingToggleError;
    case: "guardingToggleError";
  } | { case: undefined; value?: undefined };
};

/**
 * Describes the message cangate.v1.NodeEvent.
 * Use `create(NodeEventSchema)` to create a new message.
 */
export const NodeEventSchema: GenMessage<NodeEvent> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 23);

/**
 * A node guarding answer whose toggle bit was not the expected one.
 *
 * @generated from message cangate.v1.GuardingToggleError
 */
export type GuardingToggleError = Message<"cangate.v1.GuardingToggleError"> & {
  /**
   * The answer byte (bit 7 toggle, bits 0..=6 NMT state).
   *
   * @generated from field: uint32 data = 1;
   */
  data: number;

  /**
   * The toggle bit expected.
   *
   * @generated from field: bool expected_toggle = 2;
   */
  expectedToggle: boolean;

  /**
   * Toggle errors of this node so far.
   *
   * @generated from field: uint64 count = 3;
   */
  count: bigint;
};

/**
 * Describes the message cangate.v1.GuardingToggleError.
 * Use `create(GuardingToggleErrorSchema)` to create a new message.
 */
export const GuardingToggleErrorSchema: GenMessage<GuardingToggleError> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 24);

/**
 * Boot procedure succeeded.
 *
 * @generated from message cangate.v1.BootCompleted
 */
export type BootCompleted = Message<"cangate.v1.BootCompleted"> & {
};

/**
 * Describes the message cangate.v1.BootCompleted.
 * Use `create(BootCompletedSchema)` to create a new message.
 */
export const BootCompletedSchema: GenMessage<BootCompleted> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 25);

/**
 * Boot procedure failed.
 *
 * @generated from message cangate.v1.BootFailed
 */
export type BootFailed = Message<"cangate.v1.BootFailed"> & {
  /**
   * What went wrong (identity mismatch with both values, the SDO write that
   * failed with its abort, ...).
   *
   * @generated from field: string reason = 1;
   */
  reason: string;
};

/**
 * Describes the message cangate.v1.BootFailed.
 * Use `create(BootFailedSchema)` to create a new message.
 */
export const BootFailedSchema: GenMessage<BootFailed> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 26);

/**
 * StreamPdo request.
 *
 * @generated from message cangate.v1.StreamPdoRequest
 */
export type StreamPdoRequest = Message<"cangate.v1.StreamPdoRequest"> & {
  /**
   * Bus name; empty for every CANopen bus.
   *
   * @generated from field: string bus = 1;
   */
  bus: string;

  /**
   * Only these node ids, each 1..=127 (empty: all).
   *
   * @generated from field: repeated uint32 nodes = 2;
   */
  nodes: number[];
};

/**
 * Describes the message cangate.v1.StreamPdoRequest.
 * Use `create(StreamPdoRequestSchema)` to create a new message.
 */
export const StreamPdoRequestSchema: GenMessage<StreamPdoRequest> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 27);

/**
 * One mapped object of a PDO.
 *
 * @generated from message cangate.v1.PdoValue
 */
export type PdoValue = Message<"cangate.v1.PdoValue"> & {
  /**
   * Object index.
   *
   * @generated from field: uint32 index = 1;
   */
  index: number;

  /**
   * Sub-index.
   *
   * @generated from field: uint32 subindex = 2;
   */
  subindex: number;

  /**
   * Object name from the EDS (empty if unknown).
   *
   * @generated from field: string name = 3;
   */
  name: string;

  /**
   * The value.
   *
   * @generated from field: cangate.v1.Value value = 4;
   */
  value?: Value | undefined;
};

/**
 * Describes the message cangate.v1.PdoValue.
 * Use `create(PdoValueSchema)` to create a new message.
 */
export const PdoValueSchema: GenMessage<PdoValue> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 28);

/**
 * A decoded PDO, or a notice of missed PDOs.
 *
 * @generated from message cangate.v1.PdoMessage
 */
export type PdoMessage = Message<"cangate.v1.PdoMessage"> & {
  /**
   * Bus name.
   *
   * @generated from field: string bus = 1;
   */
  bus: string;

  /**
   * Node id.
   *
   * @generated from field: uint32 node = 2;
   */
  node: number;

  /**
   * PDO number (1-based).
   *
   * @generated from field: uint32 pdo = 3;
   */
  pdo: number;

  /**
   * COB-ID.
   *
   * @generated from field: uint32 cob_id = 4;
   */
  cobId: number;

  /**
   * Bus timestamp, nanoseconds since the UNIX epoch.
   *
   * @generated from field: uint64 timestamp_ns = 5;
   */
  timestampNs: bigint;

  /**
   * The mapped values in payload order.
   *
   * @generated from field: repeated cangate.v1.PdoValue values = 6;
   */
  values: PdoValue[];

  /**
   * PDOs this client missed (read too slowly) before this one; 0 normally.
   *
   * @generated from field: uint64 lost_before = 7;
   */
  lostBefore: bigint;
};

/**
 * Describes the message cangate.v1.PdoMessage.
 * Use `create(PdoMessageSchema)` to create a new message.
 */
export const PdoMessageSchema: GenMessage<PdoMessage> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 29);

/**
 * WritePdo request.
 *
 * @generated from message cangate.v1.WritePdoRequest
 */
export type WritePdoRequest = Message<"cangate.v1.WritePdoRequest"> & {
  /**
   * Bus name.
   *
   * @generated from field: string bus = 1;
   */
  bus: string;

  /**
   * Node id.
   *
   * @generated from field: uint32 node = 2;
   */
  node: number;

  /**
   * RPDO number (1-based).
   *
   * @generated from field: uint32 pdo = 3;
   */
  pdo: number;

  /**
   * One value per mapped object (index/subindex identify it; name
   * ignored). A value for an object the RPDO does not map, or a second
   * value for one, is INVALID_ARGUMENT.
   *
   * @generated from field: repeated cangate.v1.PdoValue values = 4;
   */
  values: PdoValue[];
};

/**
 * Describes the message cangate.v1.WritePdoRequest.
 * Use `create(WritePdoRequestSchema)` to create a new message.
 */
export const WritePdoRequestSchema: GenMessage<WritePdoRequest> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 30);

/**
 * WritePdo response.
 *
 * @generated from message cangate.v1.WritePdoResponse
 */
export type WritePdoResponse = Message<"cangate.v1.WritePdoResponse"> & {
  /**
   * The payload sent.
   *
   * @generated from field: bytes data = 1;
   */
  data: Uint8Array;
};

/**
 * Describes the message cangate.v1.WritePdoResponse.
 * Use `create(WritePdoResponseSchema)` to create a new message.
 */
export const WritePdoResponseSchema: GenMessage<WritePdoResponse> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 31);

/**
 * One mapped object of a PDO.
 *
 * @generated from message cangate.v1.PdoMappedObject
 */
export type PdoMappedObject = Message<"cangate.v1.PdoMappedObject"> & {
  /**
   * Object index.
   *
   * @generated from field: uint32 index = 1;
   */
  index: number;

  /**
   * Sub-index.
   *
   * @generated from field: uint32 subindex = 2;
   */
  subindex: number;

  /**
   * Length in bits (whole bytes: 8..64).
   *
   * @generated from field: uint32 bits = 3;
   */
  bits: number;

  /**
   * The object's name from the node's EDS ("" without one; ignored in
   * requests).
   *
   * @generated from field: string name = 4;
   */
  name: string;

  /**
   * In a ConfigurePdo request instead of index/subindex: the object's name
   * from the EDS ("Statusword", "Identity object.Serial number"); `bits`
   * may then be 0 and is taken from the EDS type.
   *
   * @generated from field: string object = 5;
   */
  object: string;
};

/**
 * Describes the message cangate.v1.PdoMappedObject.
 * Use `create(PdoMappedObjectSchema)` to create a new message.
 */
export const PdoMappedObjectSchema: GenMessage<PdoMappedObject> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 32);

/**
 * One PDO's communication and mapping parameters.
 *
 * @generated from message cangate.v1.PdoConfiguration
 */
export type PdoConfiguration = Message<"cangate.v1.PdoConfiguration"> & {
  /**
   * RPDO or TPDO.
   *
   * @generated from field: cangate.v1.PdoKind kind = 1;
   */
  kind: PdoKind;

  /**
   * PDO number, 1..=512.
   *
   * @generated from field: uint32 pdo = 2;
   */
  pdo: number;

  /**
   * 11-bit COB-ID (0 in ConfigurePdo: the predefined one of PDO 1..4,
   * e.g. 0x180 + node for TPDO 1).
   *
   * @generated from field: uint32 cob_id = 3;
   */
  cobId: number;

  /**
   * The PDO is valid (COB-ID bit 31 clear): the node sends or accepts it.
   *
   * @generated from field: bool enabled = 4;
   */
  enabled: boolean;

  /**
   * Transmission type: 0 acyclic synchronous, 1..=240 every n-th SYNC,
   * 252/253 on RTR, 254/255 event-driven.
   *
   * @generated from field: uint32 transmission_type = 5;
   */
  transmissionType: number;

  /**
   * TPDO inhibit time in units of 100 µs (0 = none).
   *
   * @generated from field: uint32 inhibit_time_100us = 6;
   */
  inhibitTime100us: number;

  /**
   * Event timer in ms (0 = off).
   *
   * @generated from field: uint32 event_timer_ms = 7;
   */
  eventTimerMs: number;

  /**
   * The mapped objects in payload order (at most 64 bits in all).
   *
   * @generated from field: repeated cangate.v1.PdoMappedObject mapping = 8;
   */
  mapping: PdoMappedObject[];
};

/**
 * Describes the message cangate.v1.PdoConfiguration.
 * Use `create(PdoConfigurationSchema)` to create a new message.
 */
export const PdoConfigurationSchema: GenMessage<PdoConfiguration> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 33);

/**
 * ReadPdoConfig request.
 *
 * @generated from message cangate.v1.ReadPdoConfigRequest
 */
export type ReadPdoConfigRequest = Message<"cangate.v1.ReadPdoConfigRequest"> & {
  /**
   * Bus name.
   *
   * @generated from field: string bus = 1;
   */
  bus: string;

  /**
   * Node id.
   *
   * @generated from field: uint32 node = 2;
   */
  node: number;

  /**
   * Only this kind (UNSPECIFIED: both).
   *
   * @generated from field: cangate.v1.PdoKind kind = 3;
   */
  kind: PdoKind;

  /**
   * Only this PDO number (0: PDOs 1..=4, or all the node's EDS lists).
   *
   * @generated from field: uint32 pdo = 4;
   */
  pdo: number;

  /**
   * SDO options of the reads.
   *
   * @generated from field: cangate.v1.SdoOptions options = 5;
   */
  options?: SdoOptions | undefined;
};

/**
 * Describes the message cangate.v1.ReadPdoConfigRequest.
 * Use `create(ReadPdoConfigRequestSchema)` to create a new message.
 */
export const ReadPdoConfigRequestSchema: GenMessage<ReadPdoConfigRequest> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 34);

/**
 * ReadPdoConfig response.
 *
 * @generated from message cangate.v1.ReadPdoConfigResponse
 */
export type ReadPdoConfigResponse = Message<"cangate.v1.ReadPdoConfigResponse"> & {
  /**
   * The node's PDOs, RPDOs then TPDOs, by number.
   *
   * @generated from field: repeated cangate.v1.PdoConfiguration pdos = 1;
   */
  pdos: PdoConfiguration[];
};

/**
 * Describes the message cangate.v1.ReadPdoConfigResponse.
 * Use `create(ReadPdoConfigResponseSchema)` to create a new message.
 */
export const ReadPdoConfigResponseSchema: GenMessage<ReadPdoConfigResponse> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 35);

/**
 * ConfigurePdo request.
 *
 * @generated from message cangate.v1.ConfigurePdoRequest
 */
export type ConfigurePdoRequest = Message<"cangate.v1.ConfigurePdoRequest"> & {
  /**
   * Bus name.
   *
   * @generated from field: string bus = 1;
   */
  bus: string;

  /**
   * Node id.
   *
   * @generated from field: uint32 node = 2;
   */
  node: number;

  /**
   * The PDO's new parameters (kind and number say which PDO).
   *
   * @generated from field: cangate.v1.PdoConfiguration pdo = 3;
   */
  pdo?: PdoConfiguration | undefined;

  /**
   * SDO options of the writes.
   *
   * @generated from field: cangate.v1.SdoOptions options = 4;
   */
  options?: SdoOptions | undefined;
};

/**
 * Describes the message cangate.v1.ConfigurePdoRequest.
 * Use `create(ConfigurePdoRequestSchema)` to create a new message.
 */
export const ConfigurePdoRequestSchema: GenMessage<ConfigurePdoRequest> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 36);

/**
 * ConfigurePdo response.
 *
 * @generated from message cangate.v1.ConfigurePdoResponse
 */
export type ConfigurePdoResponse = Message<"cangate.v1.ConfigurePdoResponse"> & {
  /**
   * The configuration written, as the gateway now decodes or encodes the
   * PDO (COB-ID and bit lengths filled in).
   *
   * @generated from field: cangate.v1.PdoConfiguration pdo = 1;
   */
  pdo?: PdoConfiguration | undefined;

  /**
   * The SDO writes done, in order, e.g. "0x1A00:00 = 0".
   *
   * @generated from field: repeated string writes = 2;
   */
  writes: string[];
};

/**
 * Describes the message cangate.v1.ConfigurePdoResponse.
 * Use `create(ConfigurePdoResponseSchema)` to create a new message.
 */
export const ConfigurePdoResponseSchema: GenMessage<ConfigurePdoResponse> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 37);

/**
 * GetSync request.
 *
 * @generated from message cangate.v1.GetSyncRequest
 */
export type GetSyncRequest = Message<"cangate.v1.GetSyncRequest"> & {
  /**
   * Bus name.
   *
   * @generated from field: string bus = 1;
   */
  bus: string;
};

/**
 * Describes the message cangate.v1.GetSyncRequest.
 * Use `create(GetSyncRequestSchema)` to create a new message.
 */
export const GetSyncRequestSchema: GenMessage<GetSyncRequest> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 38);

/**
 * SetSync request. Unset fields keep their current value.
 *
 * @generated from message cangate.v1.SetSyncRequest
 */
export type SetSyncRequest = Message<"cangate.v1.SetSyncRequest"> & {
  /**
   * Bus name.
   *
   * @generated from field: string bus = 1;
   */
  bus: string;

  /**
   * Start (true) or stop (false) the SYNC producer.
   *
   * @generated from field: optional bool running = 2;
   */
  running?: boolean | undefined;

  /**
   * Communication cycle period in µs (0x1006), 100..=10,000,000.
   *
   * @generated from field: optional uint32 period_us = 3;
   */
  periodUs?: number | undefined;

  /**
   * SYNC counter overflow value (0x1019): 0 no counter, 2..=240 a
   * one-byte counter running 1..=value.
   *
   * @generated from field: optional uint32 counter_overflow = 4;
   */
  counterOverflow?: number | undefined;
};

/**
 * Describes the message cangate.v1.SetSyncRequest.
 * Use `create(SetSyncRequestSchema)` to create a new message.
 */
export const SetSyncRequestSchema: GenMessage<SetSyncRequest> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 39);

/**
 * The SYNC and TIME producers of a bus.
 *
 * @generated from message cangate.v1.SyncStatus
 */
export type SyncStatus = Message<"cangate.v1.SyncStatus"> & {
  /**
   * Bus name.
   *
   * @generated from field: string bus = 1;
   */
  bus: string;

  /**
   * The SYNC producer runs.
   *
   * @generated from field: bool running = 2;
   */
  running: boolean;

  /**
   * Communication cycle period in µs (also when stopped: the period a
   * start uses).
   *
   * @generated from field: uint32 period_us = 3;
   */
  periodUs: number;

  /**
   * Counter overflow value (0: SYNC without data).
   *
   * @generated from field: uint32 counter_overflow = 4;
   */
  counterOverflow: number;

  /**
   * SYNC frames sent since the gateway started.
   *
   * @generated from field: uint64 sent = 5;
   */
  sent: bigint;

  /**
   * SYNC periods without a SYNC: the producer thread woke too late for
   * them, or the bus's transmit queue was full.
   *
   * @generated from field: uint64 skipped = 6;
   */
  skipped: bigint;

  /**
   * TIME producer period in ms (0: TIME only on request).
   *
   * @generated from field: uint32 time_period_ms = 7;
   */
  timePeriodMs: number;
};

/**
 * Describes the message cangate.v1.SyncStatus.
 * Use `create(SyncStatusSchema)` to create a new message.
 */
export const SyncStatusSchema: GenMessage<SyncStatus> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 40);

/**
 * SetTime request.
 *
 * @generated from message cangate.v1.SetTimeRequest
 */
export type SetTimeRequest = Message<"cangate.v1.SetTimeRequest"> & {
  /**
   * Bus name.
   *
   * @generated from field: string bus = 1;
   */
  bus: string;

  /**
   * Send one TIME now.
   *
   * @generated from field: bool send_now = 2;
   */
  sendNow: boolean;

  /**
   * New period of periodic TIMEs in ms (0 stops them; unset: unchanged),
   * 100 to 86,400,000.
   *
   * @generated from field: optional uint32 period_ms = 3;
   */
  periodMs?: number | undefined;
};

/**
 * Describes the message cangate.v1.SetTimeRequest.
 * Use `create(SetTimeRequestSchema)` to create a new message.
 */
export const SetTimeRequestSchema: GenMessage<SetTimeRequest> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 41);

/**
 * A CiA 301 TIME_OF_DAY.
 *
 * @generated from message cangate.v1.TimeOfDay
 */
export type TimeOfDay = Message<"cangate.v1.TimeOfDay"> & {
  /**
   * Milliseconds after midnight (UTC).
   *
   * @generated from field: uint32 ms_after_midnight = 1;
   */
  msAfterMidnight: number;

  /**
   * Days since 1984-01-01.
   *
   * @generated from field: uint32 days_since_1984 = 2;
   */
  daysSince1984: number;

  /**
   * The same instant in ms since the UNIX epoch.
   *
   * @generated from field: uint64 unix_ms = 3;
   */
  unixMs: bigint;
};

/**
 * Describes the message cangate.v1.TimeOfDay.
 * Use `create(TimeOfDaySchema)` to create a new message.
 */
export const TimeOfDaySchema: GenMessage<TimeOfDay> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 42);

/**
 * SetTime response.
 *
 * @generated from message cangate.v1.SetTimeResponse
 */
export type SetTimeResponse = Message<"cangate.v1.SetTimeResponse"> & {
  /**
   * The TIME sent (when `send_now`).
   *
   * @generated from field: cangate.v1.TimeOfDay sent = 1;
   */
  sent?: TimeOfDay | undefined;

  /**
   * TIME producer period in ms now (0: only on request).
   *
   * @generated from field: uint32 time_period_ms = 2;
   */
  timePeriodMs: number;
};

/**
 * Describes the message cangate.v1.SetTimeResponse.
 * Use `create(SetTimeResponseSchema)` to create a new message.
 */
export const SetTimeResponseSchema: GenMessage<SetTimeResponse> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 43);

/**
 * ExportDcf request.
 *
 * @generated from message cangate.v1.ExportDcfRequest
 */
export type ExportDcfRequest = Message<"cangate.v1.ExportDcfRequest"> & {
  /**
   * Bus name.
   *
   * @generated from field: string bus = 1;
   */
  bus: string;

  /**
   * Node id.
   *
   * @generated from field: uint32 node = 2;
   */
  node: number;

  /**
   * SDO options of the reads.
   *
   * @generated from field: cangate.v1.SdoOptions options = 3;
   */
  options?: SdoOptions | undefined;
};

/**
 * Describes the message cangate.v1.ExportDcfRequest.
 * Use `create(ExportDcfRequestSchema)` to create a new message.
 */
export const ExportDcfRequestSchema: GenMessage<ExportDcfRequest> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 44);

/**
 * An object a DCF export left out.
 *
 * @generated from message cangate.v1.SkippedObject
 */
export type SkippedObject = Message<"cangate.v1.SkippedObject"> & {
  /**
   * Object index.
   *
   * @generated from field: uint32 index = 1;
   */
  index: number;

  /**
   * Sub-index.
   *
   * @generated from field: uint32 subindex = 2;
   */
  subindex: number;

  /**
   * Why ("write-only", "DOMAIN (not kept in a DCF)", the SDO abort).
   *
   * @generated from field: string reason = 3;
   */
  reason: string;
};

/**
 * Describes the message cangate.v1.SkippedObject.
 * Use `create(SkippedObjectSchema)` to create a new message.
 */
export const SkippedObjectSchema: GenMessage<SkippedObject> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 45);

/**
 * ExportDcf response.
 *
 * @generated from message cangate.v1.ExportDcfResponse
 */
export type ExportDcfResponse = Message<"cangate.v1.ExportDcfResponse"> & {
  /**
   * The DCF text.
   *
   * @generated from field: string dcf = 1;
   */
  dcf: string;

  /**
   * Objects read and written into it.
   *
   * @generated from field: uint32 objects_read = 2;
   */
  objectsRead: number;

  /**
   * Objects left out.
   *
   * @generated from field: repeated cangate.v1.SkippedObject skipped = 3;
   */
  skipped: SkippedObject[];
};

/**
 * Describes the message cangate.v1.ExportDcfResponse.
 * Use `create(ExportDcfResponseSchema)` to create a new message.
 */
export const ExportDcfResponseSchema: GenMessage<ExportDcfResponse> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 46);

/**
 * Boot-up message received.
 *
 * @generated from message cangate.v1.BootUp
 */
export type BootUp = Message<"cangate.v1.BootUp"> & {
};

/**
 * Describes the message cangate.v1.BootUp.
 * Use `create(BootUpSchema)` to create a new message.
 */
export const BootUpSchema: GenMessage<BootUp> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 47);

/**
 * NMT state change.
 *
 * @generated from message cangate.v1.StateChange
 */
export type StateChange = Message<"cangate.v1.StateChange"> & {
  /**
   * Previous state (UNKNOWN the first time).
   *
   * @generated from field: cangate.v1.NmtState from = 1;
   */
  from: NmtState;

  /**
   * New state.
   *
   * @generated from field: cangate.v1.NmtState to = 2;
   */
  to: NmtState;
};

/**
 * Describes the message cangate.v1.StateChange.
 * Use `create(StateChangeSchema)` to create a new message.
 */
export const StateChangeSchema: GenMessage<StateChange> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 48);

/**
 * Heartbeat overdue, or node guarding lost.
 *
 * @generated from message cangate.v1.HeartbeatLost
 */
export type HeartbeatLost = Message<"cangate.v1.HeartbeatLost"> & {
  /**
   * The consumer timeout in ms; for node guarding the node life time
   * (guard time × life time factor).
   *
   * @generated from field: uint32 timeout_ms = 1;
   */
  timeoutMs: number;

  /**
   * Which mechanism detected the loss (HEARTBEAT or NODE_GUARDING).
   *
   * @generated from field: cangate.v1.LifeMonitoring monitoring = 2;
   */
  monitoring: LifeMonitoring;
};

/**
 * Describes the message cangate.v1.HeartbeatLost.
 * Use `create(HeartbeatLostSchema)` to create a new message.
 */
export const HeartbeatLostSchema: GenMessage<HeartbeatLost> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 49);

/**
 * Heartbeat back after a loss, or the first valid guarding answer after
 * a guarding loss.
 *
 * @generated from message cangate.v1.HeartbeatRecovered
 */
export type HeartbeatRecovered = Message<"cangate.v1.HeartbeatRecovered"> & {
  /**
   * Reported state.
   *
   * @generated from field: cangate.v1.NmtState state = 1;
   */
  state: NmtState;

  /**
   * How long the node was silent, in ms (since its last heartbeat or
   * valid guarding answer).
   *
   * @generated from field: uint64 silent_ms = 2;
   */
  silentMs: bigint;

  /**
   * Which mechanism saw it again (HEARTBEAT or NODE_GUARDING).
   *
   * @generated from field: cangate.v1.LifeMonitoring monitoring = 3;
   */
  monitoring: LifeMonitoring;
};

/**
 * Describes the message cangate.v1.HeartbeatRecovered.
 * Use `create(HeartbeatRecoveredSchema)` to create a new message.
 */
export const HeartbeatRecoveredSchema: GenMessage<HeartbeatRecovered> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 50);

/**
 * Events this client missed.
 *
 * @generated from message cangate.v1.EventsLost
 */
export type EventsLost = Message<"cangate.v1.EventsLost"> & {
  /**
   * How many.
   *
   * @generated from field: uint64 count = 1;
   */
  count: bigint;
};

/**
 * Describes the message cangate.v1.EventsLost.
 * Use `create(EventsLostSchema)` to create a new message.
 */
export const EventsLostSchema: GenMessage<EventsLost> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 51);

/**
 * The SDO abort of an error caused by an SDO transfer (ErrorInfo reason
 * SDO_ABORT, SDO_TIMEOUT, SDO_PROTOCOL_ERROR, SDO_CANCELLED or
 * SDO_NOT_SENT): packed as a
 * google.protobuf.Any with type URL
 * "type.googleapis.com/cangate.v1.SdoAbortDetails" in the details of the
 * google.rpc.Status in "grpc-status-details-bin", after the ErrorInfo (see
 * "The error model" at the top of this file). The node id is in the
 * ErrorInfo metadata ("node").
 *
 * @generated from message cangate.v1.SdoAbortDetails
 */
export type SdoAbortDetails = Message<"cangate.v1.SdoAbortDetails"> & {
  /**
   * The CiA 301 abort code on the wire, whoever sent it (0x05040000 for a
   * timeout).
   *
   * @generated from field: uint32 code = 1;
   */
  code: number;

  /**
   * Its CiA 301 name ("object does not exist in the object dictionary");
   * "unknown abort code" for a code the standard does not define.
   *
   * @generated from field: string name = 2;
   */
  name: string;

  /**
   * Object index of the transfer.
   *
   * @generated from field: uint32 index = 3;
   */
  index: number;

  /**
   * Sub-index of the transfer.
   *
   * @generated from field: uint32 subindex = 4;
   */
  subindex: number;

  /**
   * True when the node sent the abort (ErrorInfo "aborted_by" = "node");
   * false when the gateway detected a protocol violation or timeout, or
   * cancelled the transfer, and sent it ("gateway").
   *
   * @generated from field: bool from_node = 5;
   */
  fromNode: boolean;
};

/**
 * Describes the message cangate.v1.SdoAbortDetails.
 * Use `create(SdoAbortDetailsSchema)` to create a new message.
 */
export const SdoAbortDetailsSchema: GenMessage<SdoAbortDetails> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 52);

/**
 * ListSdoTransfers request.
 *
 * @generated from message cangate.v1.ListSdoTransfersRequest
 */
export type ListSdoTransfersRequest = Message<"cangate.v1.ListSdoTransfersRequest"> & {
  /**
   * Bus name.
   *
   * @generated from field: string bus = 1;
   */
  bus: string;
};

/**
 * Describes the message cangate.v1.ListSdoTransfersRequest.
 * Use `create(ListSdoTransfersRequestSchema)` to create a new message.
 */
export const ListSdoTransfersRequestSchema: GenMessage<ListSdoTransfersRequest> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 53);

/**
 * One running SDO transfer.
 *
 * @generated from message cangate.v1.SdoTransfer
 */
export type SdoTransfer = Message<"cangate.v1.SdoTransfer"> & {
  /**
   * Node id.
   *
   * @generated from field: uint32 node = 1;
   */
  node: number;

  /**
   * Object index.
   *
   * @generated from field: uint32 index = 2;
   */
  index: number;

  /**
   * Sub-index.
   *
   * @generated from field: uint32 subindex = 3;
   */
  subindex: number;

  /**
   * True for a read (upload), false for a write (download).
   *
   * @generated from field: bool upload = 4;
   */
  upload: boolean;

  /**
   * "expedited", "segmented", "block", or "" while not yet decided.
   *
   * @generated from field: string protocol = 5;
   */
  protocol: string;

  /**
   * Bytes confirmed so far.
   *
   * @generated from field: uint64 transferred = 6;
   */
  transferred: bigint;

  /**
   * Total bytes, when known.
   *
   * @generated from field: optional uint64 total = 7;
   */
  total?: bigint | undefined;
};

/**
 * Describes the message cangate.v1.SdoTransfer.
 * Use `create(SdoTransferSchema)` to create a new message.
 */
export const SdoTransferSchema: GenMessage<SdoTransfer> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 54);

/**
 * ListSdoTransfers response.
 *
 * @generated from message cangate.v1.ListSdoTransfersResponse
 */
export type ListSdoTransfersResponse = Message<"cangate.v1.ListSdoTransfersResponse"> & {
  /**
   * Transfers in progress, by node.
   *
   * @generated from field: repeated cangate.v1.SdoTransfer transfers = 1;
   */
  transfers: SdoTransfer[];
};

/**
 * Describes the message cangate.v1.ListSdoTransfersResponse.
 * Use `create(ListSdoTransfersResponseSchema)` to create a new message.
 */
export const ListSdoTransfersResponseSchema: GenMessage<ListSdoTransfersResponse> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 55);

/**
 * DownloadProgram request.
 *
 * @generated from message cangate.v1.DownloadProgramRequest
 */
export type DownloadProgramRequest = Message<"cangate.v1.DownloadProgramRequest"> & {
  /**
   * Bus name.
   *
   * @generated from field: string bus = 1;
   */
  bus: string;

  /**
   * Node id.
   *
   * @generated from field: uint32 node = 2;
   */
  node: number;

  /**
   * The program image, at most 16 MiB, at least 1 byte.
   *
   * @generated from field: bytes image = 3;
   */
  image: Uint8Array;

  /**
   * Program number: the sub-index of 0x1F50/0x1F51/0x1F56/0x1F57
   * (0 = 1; at most 254).
   *
   * @generated from field: uint32 program = 4;
   */
  program: number;

  /**
   * The software identification (0x1F56) the node must report after the
   * download; a different one fails the download with
   * PROGRAM_IDENTIFICATION_MISMATCH. Unset: not checked.
   *
   * @generated from field: optional uint32 expected_identification = 5;
   */
  expectedIdentification?: number | undefined;

  /**
   * Clear the program (0x1F51 = 3) before writing the image.
   *
   * @generated from field: bool clear = 6;
   */
  clear: boolean;

  /**
   * Longest wait for the flash status to leave "busy" after the data
   * download, ms (0 = 60000; at most 600000).
   *
   * @generated from field: uint32 flash_timeout_ms = 7;
   */
  flashTimeoutMs: number;

  /**
   * Longest wait for the boot-up after the start request, ms (0 = 10000;
   * at most 600000).
   *
   * @generated from field: uint32 boot_timeout_ms = 8;
   */
  bootTimeoutMs: number;
};

/**
 * Describes the message cangate.v1.DownloadProgramRequest.
 * Use `create(DownloadProgramRequestSchema)` to create a new message.
 */
export const DownloadProgramRequestSchema: GenMessage<DownloadProgramRequest> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 56);

/**
 * One message of the DownloadProgram stream.
 *
 * @generated from message cangate.v1.DownloadProgramProgress
 */
export type DownloadProgramProgress = Message<"cangate.v1.DownloadProgramProgress"> & {
  /**
   * The step running (of the last message: the last step done).
   *
   * @generated from field: cangate.v1.ProgramStep step = 1;
   */
  step: ProgramStep;

  /**
   * Image bytes the node confirmed so far (never decreasing; equal to
   * bytes_total once the data download is done).
   *
   * @generated from field: uint64 bytes_done = 2;
   */
  bytesDone: bigint;

  /**
   * The image's size.
   *
   * @generated from field: uint64 bytes_total = 3;
   */
  bytesTotal: bigint;

  /**
   * Set on the last message only, when the download succeeded.
   *
   * @generated from field: cangate.v1.DownloadProgramOutcome outcome = 4;
   */
  outcome?: DownloadProgramOutcome | undefined;
};

/**
 * Describes the message cangate.v1.DownloadProgramProgress.
 * Use `create(DownloadProgramProgressSchema)` to create a new message.
 */
export const DownloadProgramProgressSchema: GenMessage<DownloadProgramProgress> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 57);

/**
 * How a successful program download ended.
 *
 * @generated from message cangate.v1.DownloadProgramOutcome
 */
export type DownloadProgramOutcome = Message<"cangate.v1.DownloadProgramOutcome"> & {
  /**
   * 0x1F56 before the download; unset when the node refused the read.
   *
   * @generated from field: optional uint32 old_identification = 1;
   */
  oldIdentification?: number | undefined;

  /**
   * 0x1F56 after the node booted with the new program.
   *
   * @generated from field: uint32 new_identification = 2;
   */
  newIdentification: number;

  /**
   * Image bytes downloaded.
   *
   * @generated from field: uint64 bytes = 3;
   */
  bytes: bigint;

  /**
   * The whole download, all steps, ms.
   *
   * @generated from field: uint64 duration_ms = 4;
   */
  durationMs: bigint;

  /**
   * The data download step alone (0x1F50 block download), ms.
   *
   * @generated from field: uint64 data_duration_ms = 5;
   */
  dataDurationMs: bigint;

  /**
   * Image bytes per second of the data download step.
   *
   * @generated from field: double data_bytes_per_second = 6;
   */
  dataBytesPerSecond: number;
};

/**
 * Describes the message cangate.v1.DownloadProgramOutcome.
 * Use `create(DownloadProgramOutcomeSchema)` to create a new message.
 */
export const DownloadProgramOutcomeSchema: GenMessage<DownloadProgramOutcome> = /*@__PURE__*/
  messageDesc(file_cangate_v1_canopen, 58);

/**
 * NMT states (CiA 301).
 *
 * @generated from enum cangate.v1.NmtState
 */
export enum NmtState {
  /**
   * Never heard of.
   *
   * @generated from enum value: NMT_STATE_UNKNOWN = 0;
   */
  UNKNOWN = 0,

  /**
   * Boot-up / initialising (0x00).
   *
   * @generated from enum value: NMT_STATE_INITIALISING = 1;
   */
  INITIALISING = 1,

  /**
   * Stopped (0x04).
   *
   * @generated from enum value: NMT_STATE_STOPPED = 2;
   */
  STOPPED = 2,

  /**
   * Operational (0x05).
   *
   * @generated from enum value: NMT_STATE_OPERATIONAL = 3;
   */
  OPERATIONAL = 3,

  /**
   * Pre-operational (0x7F).
   *
   * @generated from enum value: NMT_STATE_PRE_OPERATIONAL = 4;
   */
  PRE_OPERATIONAL = 4,
}

/**
 * Describes the enum cangate.v1.NmtState.
 */
export const NmtStateSchema: GenEnum<NmtState> = /*@__PURE__*/
  enumDesc(file_cangate_v1_canopen, 0);

/**
 * NMT commands (CiA 301 command specifiers).
 *
 * @generated from enum cangate.v1.NmtCommand
 */
export enum NmtCommand {
  /**
   * Not set (refused).
   *
   * @generated from enum value: NMT_COMMAND_UNSPECIFIED = 0;
   */
  UNSPECIFIED = 0,

  /**
   * Start remote node (0x01): enter operational.
   *
   * @generated from enum value: NMT_COMMAND_START = 1;
   */
  START = 1,

  /**
   * Stop remote node (0x02).
   *
   * @generated from enum value: NMT_COMMAND_STOP = 2;
   */
  STOP = 2,

  /**
   * Enter pre-operational (0x80).
   *
   * @generated from enum value: NMT_COMMAND_ENTER_PRE_OPERATIONAL = 3;
   */
  ENTER_PRE_OPERATIONAL = 3,

  /**
   * Reset node (0x81): application and communication reset, then boot-up.
   *
   * @generated from enum value: NMT_COMMAND_RESET_NODE = 4;
   */
  RESET_NODE = 4,

  /**
   * Reset communication (0x82), then boot-up.
   *
   * @generated from enum value: NMT_COMMAND_RESET_COMMUNICATION = 5;
   */
  RESET_COMMUNICATION = 5,
}

/**
 * Describes the enum cangate.v1.NmtCommand.
 */
export const NmtCommandSchema: GenEnum<NmtCommand> = /*@__PURE__*/
  enumDesc(file_cangate_v1_canopen, 1);

/**
 * CiA 301 basic data types (codes as in the object dictionary).
 *
 * @generated from enum cangate.v1.DataType
 */
export enum DataType {
  /**
   * Not given: raw bytes only.
   *
   * @generated from enum value: DATA_TYPE_UNSPECIFIED = 0;
   */
  UNSPECIFIED = 0,

  /**
   * BOOLEAN (0x0001).
   *
   * @generated from enum value: DATA_TYPE_BOOLEAN = 1;
   */
  BOOLEAN = 1,

  /**
   * INTEGER8 (0x0002).
   *
   * @generated from enum value: DATA_TYPE_INTEGER8 = 2;
   */
  INTEGER8 = 2,

  /**
   * INTEGER16 (0x0003).
   *
   * @generated from enum value: DATA_TYPE_INTEGER16 = 3;
   */
  INTEGER16 = 3,

  /**
   * INTEGER32 (0x0004).
   *
   * @generated from enum value: DATA_TYPE_INTEGER32 = 4;
   */
  INTEGER32 = 4,

  /**
   * UNSIGNED8 (0x0005).
   *
   * @generated from enum value: DATA_TYPE_UNSIGNED8 = 5;
   */
  UNSIGNED8 = 5,

  /**
   * UNSIGNED16 (0x0006).
   *
   * @generated from enum value: DATA_TYPE_UNSIGNED16 = 6;
   */
  UNSIGNED16 = 6,

  /**
   * UNSIGNED32 (0x0007).
   *
   * @generated from enum value: DATA_TYPE_UNSIGNED32 = 7;
   */
  UNSIGNED32 = 7,

  /**
   * REAL32 (0x0008).
   *
   * @generated from enum value: DATA_TYPE_REAL32 = 8;
   */
  REAL32 = 8,

  /**
   * VISIBLE_STRING (0x0009).
   *
   * @generated from enum value: DATA_TYPE_VISIBLE_STRING = 9;
   */
  VISIBLE_STRING = 9,

  /**
   * OCTET_STRING (0x000A).
   *
   * @generated from enum value: DATA_TYPE_OCTET_STRING = 10;
   */
  OCTET_STRING = 10,

  /**
   * UNICODE_STRING (0x000B).
   *
   * @generated from enum value: DATA_TYPE_UNICODE_STRING = 11;
   */
  UNICODE_STRING = 11,

  /**
   * DOMAIN (0x000F).
   *
   * @generated from enum value: DATA_TYPE_DOMAIN = 15;
   */
  DOMAIN = 15,

  /**
   * REAL64 (0x0011).
   *
   * @generated from enum value: DATA_TYPE_REAL64 = 17;
   */
  REAL64 = 17,

  /**
   * INTEGER64 (0x0015).
   *
   * @generated from enum value: DATA_TYPE_INTEGER64 = 21;
   */
  INTEGER64 = 21,

  /**
   * UNSIGNED64 (0x001B).
   *
   * @generated from enum value: DATA_TYPE_UNSIGNED64 = 27;
   */
  UNSIGNED64 = 27,
}

/**
 * Describes the enum cangate.v1.DataType.
 */
export const DataTypeSchema: GenEnum<DataType> = /*@__PURE__*/
  enumDesc(file_cangate_v1_canopen, 2);

/**
 * How the master watches that a node is alive (CiA 301).
 *
 * @generated from enum cangate.v1.LifeMonitoring
 */
export enum LifeMonitoring {
  /**
   * Not watched (no heartbeat timeout, not guarded).
   *
   * @generated from enum value: LIFE_MONITORING_NONE = 0;
   */
  NONE = 0,

  /**
   * Heartbeat consumer: the node produces 0x700+n every producer time.
   *
   * @generated from enum value: LIFE_MONITORING_HEARTBEAT = 1;
   */
  HEARTBEAT = 1,

  /**
   * Node guarding: the master sends an RTR to 0x700+n every guard time,
   * the node answers with a toggle bit and its NMT state.
   *
   * @generated from enum value: LIFE_MONITORING_NODE_GUARDING = 2;
   */
  NODE_GUARDING = 2,
}

/**
 * Describes the enum cangate.v1.LifeMonitoring.
 */
export const LifeMonitoringSchema: GenEnum<LifeMonitoring> = /*@__PURE__*/
  enumDesc(file_cangate_v1_canopen, 3);

/**
 * Access rights of an object (EDS AccessType).
 *
 * @generated from enum cangate.v1.ObjectAccess
 */
export enum ObjectAccess {
  /**
   * Not given.
   *
   * @generated from enum value: OBJECT_ACCESS_UNSPECIFIED = 0;
   */
  UNSPECIFIED = 0,

  /**
   * "ro": read only.
   *
   * @generated from enum value: OBJECT_ACCESS_RO = 1;
   */
  RO = 1,

  /**
   * "wo": write only.
   *
   * @generated from enum value: OBJECT_ACCESS_WO = 2;
   */
  WO = 2,

  /**
   * "rw": read and write.
   *
   * @generated from enum value: OBJECT_ACCESS_RW = 3;
   */
  RW = 3,

  /**
   * "rwr": read and write, mappable into TPDOs (the device writes it).
   *
   * @generated from enum value: OBJECT_ACCESS_RWR = 4;
   */
  RWR = 4,

  /**
   * "rww": read and write, mappable into RPDOs (the bus writes it).
   *
   * @generated from enum value: OBJECT_ACCESS_RWW = 5;
   */
  RWW = 5,

  /**
   * "const": read only, never changes.
   *
   * @generated from enum value: OBJECT_ACCESS_CONST = 6;
   */
  CONST = 6,
}

/**
 * Describes the enum cangate.v1.ObjectAccess.
 */
export const ObjectAccessSchema: GenEnum<ObjectAccess> = /*@__PURE__*/
  enumDesc(file_cangate_v1_canopen, 4);

/**
 * RPDO (the node receives it) or TPDO (the node transmits it).
 *
 * @generated from enum cangate.v1.PdoKind
 */
export enum PdoKind {
  /**
   * Not given: INVALID_ARGUMENT.
   *
   * @generated from enum value: PDO_KIND_UNSPECIFIED = 0;
   */
  UNSPECIFIED = 0,

  /**
   * Receive PDO (0x1400+/0x1600+).
   *
   * @generated from enum value: PDO_KIND_RPDO = 1;
   */
  RPDO = 1,

  /**
   * Transmit PDO (0x1800+/0x1A00+).
   *
   * @generated from enum value: PDO_KIND_TPDO = 2;
   */
  TPDO = 2,
}

/**
 * Describes the enum cangate.v1.PdoKind.
 */
export const PdoKindSchema: GenEnum<PdoKind> = /*@__PURE__*/
  enumDesc(file_cangate_v1_canopen, 5);

/**
 * A step of a program download, in the order they run.
 *
 * @generated from enum cangate.v1.ProgramStep
 */
export enum ProgramStep {
  /**
   * Never sent.
   *
   * @generated from enum value: PROGRAM_STEP_UNSPECIFIED = 0;
   */
  UNSPECIFIED = 0,

  /**
   * Reading 0x1F56 before (an SDO abort here is no failure: the old
   * identification is then unknown).
   *
   * @generated from enum value: PROGRAM_STEP_READ_IDENTIFICATION_BEFORE = 1;
   */
  READ_IDENTIFICATION_BEFORE = 1,

  /**
   * Writing 0x1F51 = 0 (stop).
   *
   * @generated from enum value: PROGRAM_STEP_STOP_PROGRAM = 2;
   */
  STOP_PROGRAM = 2,

  /**
   * Writing 0x1F51 = 3 (clear), only with `clear`.
   *
   * @generated from enum value: PROGRAM_STEP_CLEAR_PROGRAM = 3;
   */
  CLEAR_PROGRAM = 3,

  /**
   * Writing the image to 0x1F50 by SDO block download.
   *
   * @generated from enum value: PROGRAM_STEP_DOWNLOAD_DATA = 4;
   */
  DOWNLOAD_DATA = 4,

  /**
   * Polling 0x1F57 until it is no longer busy.
   *
   * @generated from enum value: PROGRAM_STEP_WAIT_FLASH = 5;
   */
  WAIT_FLASH = 5,

  /**
   * Writing 0x1F51 = 1 (start).
   *
   * @generated from enum value: PROGRAM_STEP_START_PROGRAM = 6;
   */
  START_PROGRAM = 6,

  /**
   * Waiting for the node's boot-up.
   *
   * @generated from enum value: PROGRAM_STEP_WAIT_BOOT_UP = 7;
   */
  WAIT_BOOT_UP = 7,

  /**
   * Reading 0x1F56 after.
   *
   * @generated from enum value: PROGRAM_STEP_READ_IDENTIFICATION_AFTER = 8;
   */
  READ_IDENTIFICATION_AFTER = 8,
}

/**
 * Describes the enum cangate.v1.ProgramStep.
 */
export const ProgramStepSchema: GenEnum<ProgramStep> = /*@__PURE__*/
  enumDesc(file_cangate_v1_canopen, 6);

/**
 * CANopen master: nodes, NMT, SDO, events.
 *
 * @generated from service cangate.v1.Canopen
 */
export const Canopen: GenService<{
  /**
   * Nodes known on one bus (or all CANopen buses when `bus` is empty):
   * configured nodes and every node heard of (boot-up, heartbeat, EMCY,
   * scan).
   *
   * @generated from rpc cangate.v1.Canopen.ListNodes
   */
  listNodes: {
    methodKind: "unary";
    input: typeof ListNodesRequestSchema;
    output: typeof ListNodesResponseSchema;
  },
  /**
   * One node.
   *
   * @generated from rpc cangate.v1.Canopen.GetNode
   */
  getNode: {
    methodKind: "unary";
    input: typeof GetNodeRequestSchema;
    output: typeof NodeSchema;
  },
  /**
   * Sends an NMT command to one node or to all nodes (node 0).
   *
   * @generated from rpc cangate.v1.Canopen.SendNmt
   */
  sendNmt: {
    methodKind: "unary";
    input: typeof SendNmtRequestSchema;
    output: typeof SendNmtResponseSchema;
  },
  /**
   * Reads an object over SDO (expedited, segmented or block).
   *
   * @generated from rpc cangate.v1.Canopen.ReadSdo
   */
  readSdo: {
    methodKind: "unary";
    input: typeof ReadSdoRequestSchema;
    output: typeof ReadSdoResponseSchema;
  },
  /**
   * Writes an object over SDO. A write to the process or program objects
   * of an enabled axis's drive is refused unless forced (see
   * WriteSdoRequest.force).
   *
   * @generated from rpc cangate.v1.Canopen.WriteSdo
   */
  writeSdo: {
    methodKind: "unary";
    input: typeof WriteSdoRequestSchema;
    output: typeof WriteSdoResponseSchema;
  },
  /**
   * SDO reads and writes as requests and answers on one stream, for loops
   * of SDO traffic without a call per transfer. Each request carries a
   * client-chosen id; its answer carries the same id and the result of
   * ReadSdo/WriteSdo, or their error as an SdoSessionError (the stream goes
   * on). Requests to one node are answered in the order they were sent;
   * those to different nodes run concurrently, so answers of different
   * nodes may interleave. At most 64 requests of a session are outstanding
   * (sent, not yet answered): beyond that the gateway stops reading the
   * stream until an answer is out (flow control of the transport holds the
   * client back). The role is checked per request: a read as ReadSdo
   * (viewer), a write as WriteSdo (engineer); a write refused for the role
   * is a PERMISSION_DENIED answer. Each read or write counts as a call
   * against the client's call rate ([security.limits]; over it a
   * RATE_LIMIT answer). The same guards as WriteSdo apply
   * (WriteSdoRequest.force). Ending or cancelling the stream cancels its
   * outstanding transfers (the gateway aborts those on the bus); the
   * client ends its half of the stream to have every answer and then the
   * end of the stream.
   *
   * @generated from rpc cangate.v1.Canopen.SdoSession
   */
  sdoSession: {
    methodKind: "bidi_streaming";
    input: typeof SdoSessionRequestSchema;
    output: typeof SdoSessionAnswerSchema;
  },
  /**
   * A node's object dictionary as its EDS describes it (no SDO transfer):
   * every sub-object with its name, type, access, PDO mappability,
   * default and limits, in index/sub-index order. NOT_FOUND for an unknown
   * bus or node, FAILED_PRECONDITION for a node without an EDS.
   *
   * @generated from rpc cangate.v1.Canopen.ListObjects
   */
  listObjects: {
    methodKind: "unary";
    input: typeof ListObjectsRequestSchema;
    output: typeof ListObjectsResponseSchema;
  },
  /**
   * SDO transfers in progress on a bus (for progress bars of large
   * transfers: poll while a ReadSdo/WriteSdo call runs).
   *
   * @generated from rpc cangate.v1.Canopen.ListSdoTransfers
   */
  listSdoTransfers: {
    methodKind: "unary";
    input: typeof ListSdoTransfersRequestSchema;
    output: typeof ListSdoTransfersResponseSchema;
  },
  /**
   * Finds the nodes that answer an SDO read of 0x1000 (device type), all
   * 127 node ids concurrently with a short timeout, and reads their name
   * (0x1008) and identity (0x1018) where they have them.
   *
   * @generated from rpc cangate.v1.Canopen.ScanNetwork
   */
  scanNetwork: {
    methodKind: "unary";
    input: typeof ScanNetworkRequestSchema;
    output: typeof ScanNetworkResponseSchema;
  },
  /**
   * Node events as they happen: boot-up, NMT state changes, heartbeat lost
   * and recovered, EMCY. The stream ends when the client cancels it or the
   * server shuts down.
   *
   * @generated from rpc cangate.v1.Canopen.StreamNodeEvents
   */
  streamNodeEvents: {
    methodKind: "server_streaming";
    input: typeof StreamNodeEventsRequestSchema;
    output: typeof NodeEventSchema;
  },
  /**
   * Decoded TPDOs as they arrive: each mapped object with its name and
   * typed value (typed by the node's EDS; raw unsigned where unknown). The
   * TPDO layouts come from the node's configuration or its EDS defaults.
   *
   * @generated from rpc cangate.v1.Canopen.StreamPdo
   */
  streamPdo: {
    methodKind: "server_streaming";
    input: typeof StreamPdoRequestSchema;
    output: typeof PdoMessageSchema;
  },
  /**
   * Sends an RPDO built from named values (every mapped object must be
   * given; values are range-checked against the mapping's types). An RPDO
   * that maps an object commanding the drive of an enabled or moving axis
   * (controlword, mode of operation, targets, program objects) is refused
   * with FAILED_PRECONDITION, AXIS_ACTIVE, as a raw SDO write of it is.
   *
   * @generated from rpc cangate.v1.Canopen.WritePdo
   */
  writePdo: {
    methodKind: "unary";
    input: typeof WritePdoRequestSchema;
    output: typeof WritePdoResponseSchema;
  },
  /**
   * A node's PDO configuration as the node holds it now, read over SDO
   * (communication parameters 0x1400+/0x1800+ and mapping 0x1600+/0x1A00+):
   * every PDO asked for, valid or not, with its mapped objects named from
   * the EDS. PDOs the node does not have (SDO abort "object does not
   * exist") are left out. Viewer.
   *
   * @generated from rpc cangate.v1.Canopen.ReadPdoConfig
   */
  readPdoConfig: {
    methodKind: "unary";
    input: typeof ReadPdoConfigRequestSchema;
    output: typeof ReadPdoConfigResponseSchema;
  },
  /**
   * Changes one PDO of a node at run time with the CiA 301 sequence:
   * invalidate (COB-ID bit 31), transmission type, inhibit time, event
   * timer, mapping count 0, the entries, the count, then the COB-ID valid
   * (or left invalid to disable the PDO). On success StreamPdo decodes the
   * node's TPDO and WritePdo encodes its RPDO with the new layout at once.
   * A failed write is reported as an SDO error naming the object that
   * failed (e.g. "node 5, 0x1A00:01 (mapping entry 1): ... 0x06040041 ...";
   * ErrorInfo metadata "step" = "configure-pdo") and the PDO is left
   * invalid. FAILED_PRECONDITION for the PDOs of an axis's drive (the axis
   * owns its process data). Engineer.
   *
   * @generated from rpc cangate.v1.Canopen.ConfigurePdo
   */
  configurePdo: {
    methodKind: "unary";
    input: typeof ConfigurePdoRequestSchema;
    output: typeof ConfigurePdoResponseSchema;
  },
  /**
   * The SYNC producer of a bus: running, period, counter, SYNCs sent and
   * periods skipped, and the TIME producer's period. Viewer.
   *
   * @generated from rpc cangate.v1.Canopen.GetSync
   */
  getSync: {
    methodKind: "unary";
    input: typeof GetSyncRequestSchema;
    output: typeof SyncStatusSchema;
  },
  /**
   * Starts, stops or re-times the SYNC producer (0x1005/0x1006/0x1019 of
   * the master); unset fields keep their value. A stop or a new period is
   * FAILED_PRECONDITION while a cyclic (CSP) axis on the bus is moving:
   * its set-points ride every SYNC. The counter restarts at 1 after every
   * change. Engineer.
   *
   * @generated from rpc cangate.v1.Canopen.SetSync
   */
  setSync: {
    methodKind: "unary";
    input: typeof SetSyncRequestSchema;
    output: typeof SyncStatusSchema;
  },
  /**
   * The TIME producer (CiA 301 TIME_OF_DAY on 0x100, the host's UTC time):
   * sends one TIME now and/or sets the period of periodic TIMEs.
   * Engineer.
   *
   * @generated from rpc cangate.v1.Canopen.SetTime
   */
  setTime: {
    methodKind: "unary";
    input: typeof SetTimeRequestSchema;
    output: typeof SetTimeResponseSchema;
  },
  /**
   * A node's live values as a DCF (CiA 306): every readable object of its
   * EDS read over SDO and written into the EDS text as ParameterValue, with
   * a [DeviceComissioning] section. Objects the node refuses are left out
   * and listed; a node that stops answering ends the call
   * (DEADLINE_EXCEEDED). FAILED_PRECONDITION for a node without an EDS.
   * A DCF given to a node's `dcf` in the configuration is written back by
   * its boot procedure. Viewer.
   *
   * @generated from rpc cangate.v1.Canopen.ExportDcf
   */
  exportDcf: {
    methodKind: "unary";
    input: typeof ExportDcfRequestSchema;
    output: typeof ExportDcfResponseSchema;
  },
  /**
   * Downloads a program into a node (CiA 302-3 program download): reads
   * 0x1F56 (software identification), stops the program (0x1F51 = 0),
   * optionally clears it (0x1F51 = 3), writes the image to 0x1F50 by SDO
   * block download, polls 0x1F57 (flash status) until it is no longer
   * busy, starts the program (0x1F51 = 1), waits for the node's boot-up
   * and reads 0x1F56 again. The stream yields a message when each step
   * begins and as the node confirms data bytes; the last message carries
   * the outcome. Role: engineer.
   *
   * The image travels in the request, one message: this RPC accepts
   * requests up to 16 MiB + 64 KiB even when [security.limits]
   * max_message_bytes is smaller (larger images are INVALID_ARGUMENT).
   *
   * Errors end the stream: FAILED_PRECONDITION another download to the
   * node runs (reason PROGRAM_DOWNLOAD_RUNNING), or the node is the drive
   * of an axis that is enabled or moving (reason AXIS_ACTIVE, metadata
   * "axis" and "node"; refused before anything is sent, and a download
   * stops before its next step when the axis is enabled while it runs);
   * NOT_FOUND unknown bus or
   * node; an SDO failure of a step as for WriteSdo (reasons SDO_ABORT,
   * SDO_TIMEOUT, ...; the message names the step and ErrorInfo metadata
   * "step" has its ProgramStep name in lower case with dashes,
   * "download-data"); ABORTED with reason PROGRAM_FLASH_ERROR when 0x1F57
   * reports an error (metadata "flash_status" 8 hex digits,
   * "flash_error" the error code in decimal, "flash_error_name" its
   * CiA 302-3 name) or PROGRAM_IDENTIFICATION_MISMATCH (metadata
   * "expected", "found"); DEADLINE_EXCEEDED with PROGRAM_FLASH_TIMEOUT or
   * PROGRAM_NO_BOOT_UP. A client that cancels the call stops the download:
   * the SDO transfer running is aborted on the bus, and once the stop step
   * was done the node's program stays stopped (not running a half-written
   * image); a new download can follow at once.
   *
   * @generated from rpc cangate.v1.Canopen.DownloadProgram
   */
  downloadProgram: {
    methodKind: "server_streaming";
    input: typeof DownloadProgramRequestSchema;
    output: typeof DownloadProgramProgressSchema;
  },
}> = /*@__PURE__*/
  serviceDesc(file_cangate_v1_canopen, 0);

