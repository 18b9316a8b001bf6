//! The set-point streams over one CANsmc master's axes, played by the
//! master's cycle thread at every cycle start, before the axes compute
//! their set-points ([`crate::axis_runner::CycleStreams`]).
//!
//! The CANsmc counterpart of [`super::cyclic_setpoints`]: the same
//! [`SetpointPlayer`] per stream on the cycle's nominal grid (cycles the
//! thread skipped hold the playout back, so a late cycle never carries a
//! double step), the same reports and ends. The player's set-point of each
//! cycle goes to the axis ([`CansmcAxis::stream_setpoint`]), which sends it
//! in its position MDT inside its soft limits.
//!
//! A stop, quick stop, disable, fault or lost slave of an axis ends its
//! streamed motion in the axis itself (a stop ramps it down on its own stop
//! ramp); at the next cycle this table sees the axis left the stream, ends
//! the stream and ramps its other axes to rest together.

use super::cyclic_setpoints::{PlayedStream, StreamEnd, StreamReport, close_stream};
use crate::axis_runner::CycleStreams;
use cangate_axis::Activity;
use cangate_axis::cansmc::CansmcAxis;
use cangate_axis::setpoint_stream::{
    AxisLimits, PlayerConfig, PlayerState, PointRefused, SetpointPlayer, StreamPoint,
};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// A stream of the cycle thread: `extra` is whether the thread handed
/// the axes to it.
type CycleStream = PlayedStream<bool>;

#[derive(Debug, Default)]
struct State {
    /// Per axis of the master: its name and the stream that drives it.
    axes: Vec<(String, Option<u64>)>,
    streams: Vec<CycleStream>,
    next_stream: u64,
}

impl State {
    fn stream(&mut self, id: u64) -> Option<&mut CycleStream> {
        self.streams.iter_mut().find(|s| s.id == id)
    }
}

/// The streams of one CANsmc master, shared by the sessions and the
/// master's cycle thread; axes are indexed as the master's.
#[derive(Debug)]
pub struct CansmcSetpoints {
    /// The clock of the players.
    origin: Instant,
    state: Mutex<State>,
}

impl CansmcSetpoints {
    /// A table for the master's axes (names in its order).
    pub fn new(names: impl IntoIterator<Item = String>) -> CansmcSetpoints {
        CansmcSetpoints {
            origin: Instant::now(),
            state: Mutex::new(State {
                axes: names.into_iter().map(|n| (n, None)).collect(),
                ..State::default()
            }),
        }
    }

    /// Opens a stream over `axes` (the master's indices), each with its
    /// limits and the position it stands at: the cycle thread hands the
    /// axes to it at the next cycle (an axis that moved or left operation
    /// enabled meanwhile ends it at once).
    ///
    /// # Errors
    /// Why an axis cannot be streamed, for a person.
    pub fn open_stream(
        &self,
        axes: &[usize],
        limits: Vec<AxisLimits>,
        positions: Vec<f64>,
        cfg: PlayerConfig,
    ) -> Result<u64, String> {
        let mut st = self.state.lock().expect("stream table lock");
        for &i in axes {
            let (name, stream) = &st.axes[i];
            if stream.is_some() {
                return Err(format!("axis {name} is already in a set-point stream"));
            }
        }
        let id = st.next_stream;
        st.next_stream += 1;
        for &i in axes {
            st.axes[i].1 = Some(id);
        }
        st.streams.push(PlayedStream::new(
            id,
            axes,
            SetpointPlayer::new(cfg, limits, positions),
            false,
        ));
        Ok(id)
    }

    /// Takes points of stream `id` that arrived now: the refused ones with
    /// their position in `points` and the reason.
    pub fn push_points(
        &self,
        id: u64,
        points: impl IntoIterator<Item = StreamPoint>,
    ) -> Vec<(usize, PointRefused)> {
        let now = self.origin.elapsed();
        let mut st = self.state.lock().expect("stream table lock");
        let Some(s) = st.stream(id) else {
            return Vec::new();
        };
        let arrived = now.saturating_sub(s.held_back);
        points
            .into_iter()
            .enumerate()
            .filter_map(|(k, p)| s.player.push(p, arrived).err().map(|e| (k, e)))
            .collect()
    }

    /// Brings stream `id` to rest and ends it (its first reason stays).
    pub fn stop_stream(&self, id: u64, reason: StreamEnd) {
        let now = self.origin.elapsed();
        let mut st = self.state.lock().expect("stream table lock");
        if let Some(s) = st.stream(id) {
            s.stop(reason, now);
        }
    }

    /// Whether axis `i` (the master's index) is driven by a stream.
    pub fn in_stream(&self, i: usize) -> bool {
        let st = self.state.lock().expect("stream table lock");
        st.axes.get(i).is_some_and(|(_, s)| s.is_some())
    }

    /// Where stream `id` stands; its events since the last report.
    pub fn report(&self, id: u64) -> Option<StreamReport> {
        let now = self.origin.elapsed();
        let mut st = self.state.lock().expect("stream table lock");
        Some(st.stream(id)?.report(now))
    }

    /// The session of stream `id` is gone: a stream still playing ramps to
    /// rest (ended by `reason` unless it had ended already) and is dropped
    /// once at rest.
    pub fn close_stream(&self, id: u64, reason: StreamEnd) {
        let now = self.origin.elapsed();
        let mut st = self.state.lock().expect("stream table lock");
        close_stream(&mut st.streams, id, reason, now);
    }
}

/// Why axis `name` left its stream: a stop (it ramps down on its own stop
/// ramp), or it left operation enabled.
fn left(name: &str, axis: &CansmcAxis) -> StreamEnd {
    let axis_name = name.to_string();
    if axis.activity() == Activity::Stopping {
        StreamEnd::Stopped { axis: axis_name }
    } else {
        StreamEnd::AxisLeft { axis: axis_name }
    }
}

impl CycleStreams for CansmcSetpoints {
    fn play(&self, at: Instant, missed: Duration, axes: &mut [&mut CansmcAxis]) {
        let t = at.saturating_duration_since(self.origin);
        let mut st = self.state.lock().expect("stream table lock");
        let State {
            axes: entries,
            streams,
            ..
        } = &mut *st;
        for s in streams.iter_mut().filter(|s| !s.finished) {
            if !s.extra {
                s.extra = true;
                let from = s.player.position().to_vec();
                for (k, &i) in s.axes.iter().enumerate() {
                    if let Err(e) = axes[i].start_stream(from[k]) {
                        tracing::info!(axis = %entries[i].0, error = %e, "set-point stream not started");
                        let reason = left(&entries[i].0, axes[i]);
                        if s.end.is_none() {
                            s.end = Some(reason);
                        }
                        break;
                    }
                }
                if s.end.is_some() {
                    // Nothing moved: every axis holds where it stands.
                    for &i in &s.axes {
                        axes[i].end_stream();
                        entries[i].1 = None;
                    }
                    s.finished = true;
                    continue;
                }
            }
            s.held_back += missed;
            for k in 0..s.axes.len() {
                let i = s.axes[k];
                if entries[i].1 == Some(s.id) && !axes[i].is_streamed() {
                    // A stop, a disable, a fault or a lost slave: the axis
                    // follows its own motion; the others ramp to rest.
                    entries[i].1 = None;
                    let reason = left(&entries[i].0, axes[i]);
                    s.stop(reason, t);
                }
            }
            let cycle = s.player.next(t.saturating_sub(s.held_back));
            if let Some(ev) = cycle.event {
                s.events.push(ev);
            }
            // Ended and at rest: each axis holds where the stream left it.
            let done = s.end.is_some() && cycle.state == PlayerState::Waiting;
            for (k, &i) in s.axes.iter().enumerate() {
                if entries[i].1 != Some(s.id) {
                    continue;
                }
                let v = if done { 0.0 } else { s.player.velocity()[k] };
                axes[i].stream_setpoint(cycle.positions[k], v);
                if done {
                    axes[i].end_stream();
                    entries[i].1 = None;
                }
            }
            s.finished = done;
        }
        streams.retain(|s| !(s.finished && s.orphaned));
    }
}
