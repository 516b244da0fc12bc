"""A DSACON32m command and its reply: send, wait boundedly, skip what is not the answer.

The part of ``DSAClient`` that talks in commands; the client provides the link (``_write``,
``_pump``, ``parser``, ``_replies``, ``_counts``, the timeouts), this decides when a wait is over.
"""

from __future__ import annotations

import time

from firmware_io.client_types import DSATimeout
from firmware_io.wire import requests as R
from firmware_io.wire.errors import DSAError
from firmware_io.wire.packets import check_reply

__all__ = ["CommandExchange"]


class CommandExchange:
    """Mixed into ``DSAClient``: commands, acknowledgements and the stop handshake."""

    def _request(
        self, packet: bytes, reply_id: int, frames_limit: int | None = -1, timeout: float | None = None
    ) -> bytes:
        """Send a command and return its reply payload.

        Frames arriving meanwhile are queued. At most ``max_skipped_frames`` may arrive before
        the reply (``frames_limit=None``: any number, bounded by ``timeout``); replies with another
        id (late answers to earlier commands) are counted and skipped. The wait ends after
        ``gap_timeout`` without a byte, or at a total deadline (``timeout``, default
        ``reply_timeout``, and never past the open's own deadline) that arriving bytes do not extend.
        """
        if frames_limit == -1:
            frames_limit = self.max_skipped_frames
        self._replies.clear()
        self._write(packet)
        sent = time.monotonic()
        bytes_before = self.parser.stats.bytes_in
        frames_before = self._frames_seen()
        limit = self.reply_timeout if timeout is None else timeout
        deadline = sent + limit
        whole_open = self._open_deadline is not None and self._open_deadline < deadline
        if whole_open:
            deadline = self._open_deadline
        while True:
            while self._replies:
                reply = self._replies.popleft()
                if reply.packet_id == reply_id:
                    self._replies.clear()
                    return reply.payload
                self._counts["unexpected_replies"] += 1
            if frames_limit is not None and self._frames_seen() - frames_before > frames_limit:
                self._counts["timeouts"] += 1
                raise DSATimeout(f"{self.url}: no reply to command 0x{reply_id:02X} within {frames_limit} frames")
            now = time.monotonic()
            if now >= deadline:
                self._counts["timeouts"] += 1
                raise DSATimeout(self._no_reply(reply_id, limit, bytes_before, whole_open))
            quiet = now - max(sent, self._last_rx)
            if quiet >= self.gap_timeout:
                if self.parser.pending:
                    self._dispatch(self.parser.flush_pending())
                    if self._replies:
                        continue
                self._counts["timeouts"] += 1
                raise DSATimeout(
                    f"{self.url}: no reply to command 0x{reply_id:02X} (silent for {self.gap_timeout:g} s)"
                )
            self._pump(min(self.gap_timeout - quiet, deadline - now))

    def _no_reply(self, reply_id: int, limit: float, bytes_before: int, whole_open: bool) -> str:
        """The timeout message; bytes that came but made no reply point at the line, not the device."""
        if whole_open:
            text = f"{self.url}: open did not complete within {self.open_timeout:g} s (no reply to command 0x{reply_id:02X})"
            bytes_before = self._open_bytes
        else:
            text = f"{self.url}: no reply to command 0x{reply_id:02X} within {limit:.3g} s"
        n_bytes = max(0, self.parser.stats.bytes_in - bytes_before)
        if n_bytes > 0:
            text += (f" although {n_bytes} bytes arrived that were not a valid reply "
                     "(check the baud rate, and that this port or address is the DSACON32m and no other device)")
        return text

    def _frames_seen(self) -> int:
        c = self._counts
        return c["frames"] + c["frames_ignored"] + c["decode_errors"] + c["frames_implausible"]

    def _ack(self, packet: bytes, frames_limit: int | None = -1, timeout: float | None = None) -> None:
        payload = self._request(packet, packet[3], frames_limit, timeout)
        check_reply(payload, packet[3])

    def _command(self, packet: bytes, expect_reply: bool) -> None:
        if expect_reply:
            self._ack(packet)
        else:
            self._write(packet)

    def _send_stop(self, tries: int, timeout: float | None = None) -> bool:
        """Send stop up to ``tries`` times; True once acknowledged. Device errors count as not acked."""
        for _ in range(tries):
            try:
                self._ack(R.stop_request(rle=self.rle), frames_limit=None, timeout=timeout or self.stop_timeout)
                return True
            except DSAError:
                continue
        return False
