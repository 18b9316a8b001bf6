//! Server streams as `Stream`s of typed items with this crate's [`Error`].

use crate::error::Error;
use futures::stream::{BoxStream, StreamExt};

/// A live stream of `T` from the gateway: `Ok` items until the gateway
/// ends the stream (`None`) or it fails (one `Err`, then usually `None`).
/// Dropping it cancels the call.
pub type EventStream<T> = BoxStream<'static, Result<T, Error>>;

/// Each message of `stream` turned into zero or more items by `items`
/// (batches become single items; messages of no interest vanish).
pub(crate) fn flat_map<M, T, I>(
    stream: tonic::Streaming<M>,
    items: impl Fn(M) -> I + Send + 'static,
) -> EventStream<T>
where
    M: Send + 'static,
    T: Send + 'static,
    I: IntoIterator<Item = T>,
    I::IntoIter: Send + 'static,
{
    stream
        .flat_map(move |message| match message {
            Ok(m) => futures::stream::iter(items(m).into_iter().map(Ok)).left_stream(),
            Err(status) => {
                futures::stream::once(async move { Err(Error::from(status)) }).right_stream()
            }
        })
        .boxed()
}

/// Each message of `stream` as one item.
pub(crate) fn map<M, T>(
    stream: tonic::Streaming<M>,
    item: impl Fn(M) -> T + Send + 'static,
) -> EventStream<T>
where
    M: Send + 'static,
    T: Send + 'static,
{
    stream
        .map(move |message| message.map(&item).map_err(Error::from))
        .boxed()
}
