//! Program download (CiA 302-3) through the gateway: [`Canopen::download_program`].

use crate::canopen::{Canopen, millis};
use crate::error::Error;
use crate::pb;
use crate::sdo::NodeId;
use crate::streams::{self, EventStream};
use futures::StreamExt;
use std::time::Duration;

/// Options of a program download; the defaults are program 1, no expected
/// identification, no clear, the gateway's default waits.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ProgramOptions {
    /// Program number: the sub-index of 0x1F50/51/56/57 (`None`: 1).
    pub program: Option<u8>,
    /// The software identification (0x1F56) the node must report after.
    pub expected_identification: Option<u32>,
    /// Clear the program (0x1F51 = 3) before writing it.
    pub clear: bool,
    /// Longest wait for the flash status after the data (`None`: 60 s).
    pub flash_timeout: Option<Duration>,
    /// Longest wait for the boot-up after the start (`None`: 10 s).
    pub boot_timeout: Option<Duration>,
}

impl Canopen {
    /// Downloads `image` as a program into `node` (CiA 302-3): a stream of
    /// progress messages; the last one carries the outcome, a failure ends
    /// it with one `Err` (an SDO abort of a step is [`Error::SdoAbort`], a
    /// flash status error [`Error::Refused`] with reason
    /// "PROGRAM_FLASH_ERROR", ...). Dropping the stream cancels the
    /// download (the gateway aborts the transfer running).
    pub async fn download_program(
        &self,
        node: NodeId,
        image: Vec<u8>,
        opts: &ProgramOptions,
    ) -> Result<EventStream<pb::DownloadProgramProgress>, Error> {
        let req = pb::DownloadProgramRequest {
            bus: self.bus().to_string(),
            node: node.into(),
            image,
            program: opts.program.map_or(0, u32::from),
            expected_identification: opts.expected_identification,
            clear: opts.clear,
            flash_timeout_ms: opts.flash_timeout.map_or(0, millis),
            boot_timeout_ms: opts.boot_timeout.map_or(0, millis),
        };
        let s = self
            .client()
            .call(
                "DownloadProgram",
                None,
                self.client().canopen_client().download_program(req),
            )
            .await?;
        Ok(streams::map(s, |m| m))
    }

    /// [`Canopen::download_program`] to its end: `progress` sees every
    /// message; the outcome is returned.
    pub async fn download_program_with(
        &self,
        node: NodeId,
        image: Vec<u8>,
        opts: &ProgramOptions,
        mut progress: impl FnMut(&pb::DownloadProgramProgress),
    ) -> Result<pb::DownloadProgramOutcome, Error> {
        let mut s = self.download_program(node, image, opts).await?;
        while let Some(m) = s.next().await {
            let m = m?;
            progress(&m);
            if let Some(o) = m.outcome {
                return Ok(o);
            }
        }
        Err(Error::Transport {
            message: "the DownloadProgram stream ended without an outcome".into(),
        })
    }
}
