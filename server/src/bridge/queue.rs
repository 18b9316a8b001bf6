//! The publish queue of one broker connection, sans-IO: it numbers each
//! stream's messages, holds them while the broker is away, knows which
//! publish the broker acknowledged, and turns every message it cannot keep
//! into a gap record. Nothing leaves the queue unaccounted: a message is
//! written (QoS 0), acknowledged (QoS 1), or covered by a gap.
//!
//! The MQTT client reports each publish it writes (`on_written`, with the
//! packet id it chose) in the order it was handed them, and each
//! acknowledgement by packet id (`on_acked`). The queue hands over at most
//! `window` publishes not yet settled, so the written reports can be
//! matched to its items in order. When the connection ends, every item not
//! acknowledged goes back to the front, in order, to be sent again on the
//! next connection (the client forgets them: clean session): items the
//! broker may already have are sent again (a consumer can see a sequence
//! number twice, never miss one silently), and are never dropped.

use std::collections::{BTreeMap, HashMap, VecDeque};

/// Why messages were not published (as the proto's `GapReason`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GapReason {
    /// The queue was full: the oldest message never sent was dropped.
    QueueFull,
    /// The gateway's stream dropped events before the bridge read them.
    SourceLagged,
}

/// Messages of one stream that were not published.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Gap {
    /// The stream.
    pub stream: String,
    /// First missing sequence number.
    pub first: u64,
    /// Last missing sequence number (inclusive).
    pub last: u64,
    /// Why.
    pub reason: GapReason,
}

/// What an item carries: a message of a stream, or a gap record.
#[derive(Debug, Clone, PartialEq)]
pub enum Payload<T> {
    /// A message, encoded.
    Message(T),
    /// A gap record, encoded by the caller when it is sent.
    Gap(Gap),
}

/// One publish.
#[derive(Debug, Clone, PartialEq)]
pub struct Item<T> {
    /// The stream (topic below the gateway's level).
    pub stream: String,
    /// Its number in the stream (0: a state such as the status, not
    /// numbered).
    pub seq: u64,
    /// QoS 1 (acknowledged) rather than QoS 0.
    pub acked: bool,
    /// Retained by the broker.
    pub retain: bool,
    /// What it carries.
    pub payload: Payload<T>,
    /// May be dropped when the queue is full (a message never written;
    /// not a gap record nor a state).
    droppable: bool,
    /// Order of the item in the queue (to put items back in order).
    order: u64,
}

/// What the queue did, for the metrics.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct Settled {
    /// Publishes written at QoS 0.
    pub written: u64,
    /// Publishes the broker acknowledged.
    pub acknowledged: u64,
}

/// The queue of one connection.
#[derive(Debug)]
pub struct Queue<T> {
    capacity: usize,
    window: usize,
    connected: bool,
    /// Waiting to be sent, oldest first (items sent before and put back
    /// first of all).
    waiting: VecDeque<Item<T>>,
    /// Droppable items in `waiting`.
    droppable: usize,
    /// Handed to the client, not yet reported written, in order.
    handed: VecDeque<Item<T>>,
    /// Written at QoS 1, not yet acknowledged: packet id → item.
    in_flight: BTreeMap<u16, Item<T>>,
    /// Gap records not yet queued (merged while they grow).
    gaps: Vec<Gap>,
    next_seq: HashMap<String, u64>,
    next_order: u64,
    /// Messages recorded in gaps since the last `take_new_gaps`: queue
    /// full, source lagged.
    new_gaps: (u64, u64),
}

/// The stream that carries the gap records of `stream`: its bus's
/// `bus/<bus>/gap`, or `gap` for a stream of no bus.
pub fn gap_stream(stream: &str) -> String {
    let mut parts = stream.splitn(3, '/');
    match (parts.next(), parts.next()) {
        (Some("bus"), Some(bus)) if !bus.is_empty() => format!("bus/{bus}/gap"),
        _ => "gap".to_string(),
    }
}

impl<T: Clone> Queue<T> {
    /// A queue holding at most `capacity` messages not yet sent, with at
    /// most `window` publishes handed to the client and not settled.
    pub fn new(capacity: usize, window: usize) -> Self {
        Queue {
            capacity: capacity.max(1),
            window: window.max(1),
            connected: false,
            waiting: VecDeque::new(),
            droppable: 0,
            handed: VecDeque::new(),
            in_flight: BTreeMap::new(),
            gaps: Vec::new(),
            next_seq: HashMap::new(),
            next_order: 0,
            new_gaps: (0, 0),
        }
    }

    fn take_seq(&mut self, stream: &str, n: u64) -> u64 {
        let next = self.next_seq.entry(stream.to_string()).or_insert(1);
        let first = *next;
        *next += n;
        first
    }

    fn order(&mut self) -> u64 {
        self.next_order += 1;
        self.next_order
    }

    /// Queues the next message of `stream`; `encode` gets its sequence
    /// number. When the queue is full, the oldest message never sent is
    /// dropped and recorded as a gap. Returns the sequence number.
    pub fn push(
        &mut self,
        stream: &str,
        acked: bool,
        retain: bool,
        encode: impl FnOnce(u64) -> T,
    ) -> u64 {
        let seq = self.take_seq(stream, 1);
        if self.droppable >= self.capacity {
            self.drop_oldest();
        }
        let order = self.order();
        self.waiting.push_back(Item {
            stream: stream.to_string(),
            seq,
            acked,
            retain,
            payload: Payload::Message(encode(seq)),
            droppable: true,
            order,
        });
        self.droppable += 1;
        seq
    }

    /// Queues a state message (not numbered, never dropped) ahead of every
    /// message: the status at each connection.
    pub fn push_state_first(&mut self, stream: &str, retain: bool, message: T) {
        let order = self.order();
        self.waiting.push_front(Item {
            stream: stream.to_string(),
            seq: 0,
            acked: true,
            retain,
            payload: Payload::Message(message),
            droppable: false,
            order,
        });
    }

    /// `n` messages of `stream` were lost before the queue saw them: their
    /// numbers are taken and recorded as a gap.
    pub fn lost(&mut self, stream: &str, n: u64) {
        if n == 0 {
            return;
        }
        let first = self.take_seq(stream, n);
        self.add_gap(stream, first, first + n - 1, GapReason::SourceLagged);
    }

    fn drop_oldest(&mut self) {
        let Some(i) = self.waiting.iter().position(|it| it.droppable) else {
            return;
        };
        let item = self.waiting.remove(i).expect("position is in range");
        self.droppable -= 1;
        self.add_gap(&item.stream, item.seq, item.seq, GapReason::QueueFull);
    }

    fn add_gap(&mut self, stream: &str, first: u64, last: u64, reason: GapReason) {
        match reason {
            GapReason::QueueFull => self.new_gaps.0 += last - first + 1,
            GapReason::SourceLagged => self.new_gaps.1 += last - first + 1,
        }
        if let Some(g) = (self.gaps.iter_mut().rev()).find(|g| g.stream == stream)
            && g.reason == reason
            && g.last + 1 == first
        {
            g.last = last;
            return;
        }
        self.gaps.push(Gap {
            stream: stream.to_string(),
            first,
            last,
            reason,
        });
    }

    /// The connection is up: items may be handed over.
    pub fn on_connected(&mut self) {
        self.connected = true;
    }

    /// The connection ended: every item not acknowledged is put back, in
    /// order, ahead of the rest; those the broker may have (written at
    /// QoS 1) are never dropped.
    pub fn on_disconnected(&mut self) {
        self.connected = false;
        let mut back: Vec<Item<T>> = std::mem::take(&mut self.in_flight)
            .into_values()
            .map(|mut it| {
                it.droppable = false;
                it
            })
            .collect();
        back.extend(self.handed.drain(..));
        back.sort_by_key(|it| it.order);
        for it in back.into_iter().rev() {
            if it.droppable {
                self.droppable += 1;
            }
            self.waiting.push_front(it);
        }
    }

    /// The next publish to hand to the client, if connected and the
    /// window allows: items put back first, then gap records, then
    /// messages in order. `gap_seq` is called for a gap record's own
    /// number in its gap stream.
    pub fn next_to_send(&mut self) -> Option<Item<T>> {
        if !self.connected || self.handed.len() + self.in_flight.len() >= self.window {
            return None;
        }
        let resend = self.waiting.front().is_some_and(|it| !it.droppable);
        let item = if !resend && !self.gaps.is_empty() {
            let gap = self.gaps.remove(0);
            let stream = gap_stream(&gap.stream);
            let seq = self.take_seq(&stream, 1);
            let order = self.order();
            Item {
                stream,
                seq,
                acked: true,
                retain: false,
                payload: Payload::Gap(gap),
                droppable: false,
                order,
            }
        } else {
            let it = self.waiting.pop_front()?;
            if it.droppable {
                self.droppable -= 1;
            }
            it
        };
        self.handed.push_back(item.clone());
        Some(item)
    }

    /// The client wrote the oldest publish handed to it, with packet id
    /// `pkid` (0 at QoS 0).
    pub fn on_written(&mut self, pkid: u16) -> Settled {
        let Some(it) = self.handed.pop_front() else {
            return Settled::default();
        };
        if it.acked {
            self.in_flight.insert(pkid, it);
            Settled::default()
        } else {
            Settled {
                written: 1,
                acknowledged: 0,
            }
        }
    }

    /// The broker acknowledged packet `pkid`.
    pub fn on_acked(&mut self, pkid: u16) -> Settled {
        match self.in_flight.remove(&pkid) {
            Some(_) => Settled {
                written: 0,
                acknowledged: 1,
            },
            None => Settled::default(),
        }
    }

    /// Messages recorded in gaps since the last call (queue full, source
    /// lagged), for the metrics.
    pub fn take_new_gaps(&mut self) -> (u64, u64) {
        std::mem::take(&mut self.new_gaps)
    }

    /// Messages waiting (not yet handed over).
    pub fn waiting(&self) -> usize {
        self.waiting.len()
    }

    /// Publishes handed over and not yet reported written.
    pub fn handed(&self) -> usize {
        self.handed.len()
    }

    /// Publishes handed over and not yet settled.
    pub fn unsettled(&self) -> usize {
        self.handed.len() + self.in_flight.len()
    }

    /// Nothing waiting, handed over or recorded: everything settled.
    pub fn is_idle(&self) -> bool {
        self.waiting.is_empty() && self.unsettled() == 0 && self.gaps.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sends everything the queue hands over, writes it with packet ids
    /// from `pkid`, and returns what went out.
    fn send_all(q: &mut Queue<u64>, pkid: &mut u16) -> Vec<Item<u64>> {
        let mut out = Vec::new();
        while let Some(it) = q.next_to_send() {
            *pkid += 1;
            q.on_written(if it.acked { *pkid } else { 0 });
            out.push(it);
        }
        out
    }

    fn seqs(items: &[Item<u64>], stream: &str) -> Vec<u64> {
        (items.iter())
            .filter(|it| it.stream == stream)
            .map(|it| it.seq)
            .collect()
    }

    #[test]
    fn streams_are_numbered_from_one_each() {
        let mut q = Queue::new(10, 10);
        assert_eq!(q.push("a", true, false, |s| s), 1);
        assert_eq!(q.push("b", true, false, |s| s), 1);
        assert_eq!(q.push("a", true, false, |s| s), 2);
        q.on_connected();
        let out = send_all(&mut q, &mut 0);
        assert_eq!(seqs(&out, "a"), [1, 2]);
        assert_eq!(seqs(&out, "b"), [1]);
    }

    #[test]
    fn a_full_queue_drops_the_oldest_and_records_exactly_those() {
        let mut q = Queue::new(3, 100);
        for _ in 0..10 {
            q.push("bus/can0/node/5/event", true, false, |s| s);
        }
        q.on_connected();
        let out = send_all(&mut q, &mut 0);
        let gap = out.iter().find_map(|it| match &it.payload {
            Payload::Gap(g) => Some((it.stream.clone(), it.seq, g.clone())),
            _ => None,
        });
        assert_eq!(
            gap,
            Some((
                "bus/can0/gap".to_string(),
                1,
                Gap {
                    stream: "bus/can0/node/5/event".into(),
                    first: 1,
                    last: 7,
                    reason: GapReason::QueueFull
                }
            ))
        );
        assert_eq!(seqs(&out, "bus/can0/node/5/event"), [8, 9, 10]);
    }

    #[test]
    fn acknowledged_items_are_settled_and_the_rest_sent_again_in_order() {
        let mut q = Queue::new(100, 100);
        for _ in 0..5 {
            q.push("e", true, false, |s| s);
        }
        q.on_connected();
        let out = send_all(&mut q, &mut 0);
        assert_eq!(seqs(&out, "e"), [1, 2, 3, 4, 5]);
        // The broker acknowledges 1 and 3 (packet ids 1 and 3), then the
        // connection ends.
        assert_eq!(q.on_acked(1).acknowledged, 1);
        assert_eq!(q.on_acked(3).acknowledged, 1);
        assert_eq!(q.on_acked(3).acknowledged, 0, "an ack counts once");
        q.on_disconnected();
        assert_eq!(q.next_to_send(), None, "nothing is handed over while away");
        q.push("e", true, false, |s| s);
        q.on_connected();
        let again = send_all(&mut q, &mut 10);
        assert_eq!(seqs(&again, "e"), [2, 4, 5, 6]);
    }

    #[test]
    fn items_the_broker_may_have_are_never_dropped() {
        let mut q = Queue::new(2, 100);
        q.push("e", true, false, |s| s);
        q.push("e", true, false, |s| s);
        q.on_connected();
        send_all(&mut q, &mut 0); // 1, 2 written, not acknowledged
        q.on_disconnected();
        for _ in 0..5 {
            q.push("e", true, false, |s| s); // 3..=7, room for two
        }
        q.on_connected();
        let out = send_all(&mut q, &mut 10);
        assert_eq!(seqs(&out, "e"), [1, 2, 6, 7]);
        let gaps: Vec<_> = (out.iter())
            .filter_map(|it| match &it.payload {
                Payload::Gap(g) => Some((g.first, g.last)),
                _ => None,
            })
            .collect();
        assert_eq!(gaps, [(3, 5)]);
    }

    #[test]
    fn the_window_limits_what_is_handed_over() {
        let mut q = Queue::new(100, 2);
        for _ in 0..5 {
            q.push("e", true, false, |s| s);
        }
        q.on_connected();
        assert!(q.next_to_send().is_some());
        assert!(q.next_to_send().is_some());
        assert!(q.next_to_send().is_none());
        q.on_written(1);
        assert!(q.next_to_send().is_none(), "written but not acknowledged");
        q.on_acked(1);
        assert!(q.next_to_send().is_some());
    }

    #[test]
    fn lost_source_events_take_their_numbers_as_a_gap() {
        let mut q = Queue::new(10, 10);
        q.push("bus/can0/stats", false, false, |s| s);
        q.lost("bus/can0/stats", 3);
        q.push("bus/can0/stats", false, false, |s| s);
        q.on_connected();
        let out = send_all(&mut q, &mut 0);
        assert_eq!(seqs(&out, "bus/can0/stats"), [1, 5]);
        assert!(out.iter().any(|it| it.payload
            == Payload::Gap(Gap {
                stream: "bus/can0/stats".into(),
                first: 2,
                last: 4,
                reason: GapReason::SourceLagged
            })));
        assert_eq!(gap_stream("status"), "gap");
    }

    #[test]
    fn qos0_items_are_settled_when_written_and_the_state_goes_first() {
        let mut q = Queue::new(10, 10);
        q.push("bus/can0/frames", false, false, |s| s);
        q.push_state_first("status", true, 99);
        q.on_connected();
        let first = q.next_to_send().unwrap();
        assert_eq!((first.stream.as_str(), first.seq), ("status", 0));
        assert_eq!(q.on_written(7), Settled::default());
        let frames = q.next_to_send().unwrap();
        assert!(!frames.acked);
        assert_eq!(q.on_written(0).written, 1);
        q.on_acked(7);
        assert!(q.is_idle());
    }
}
