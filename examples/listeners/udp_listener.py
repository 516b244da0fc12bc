"""Listens for handover events over UDP and prints one line per event (docs/EVENTS.md).

    python3 udp_listener.py 5005        # daemon config: [sinks] udp = ["127.0.0.1:5005"]
    python3 udp_listener.py 0 3         # any free port (printed first); exit after 3 events

Standard library only. Each datagram is one JSON object; lines of a type this listener does
not know are skipped, and a newer protocol number is reported once.
"""

import json
import socket
import sys

PROTOCOL = 1


def describe(event: dict) -> str | None:
    """The line to print, or None for a line type this listener does not know."""
    if event.get("type") == "decision":
        return (f"decision {event['class']} latency_us={event['latency_us']} model={event['model_id']} "
                f"frame_last={event['frame_last']}")
    if event.get("type") == "model":
        previous = event["previous_model_id"] or "null"
        return f"model {event['model_id']} version={event['model_version']} previous={previous}"
    return None


def main(port: int = 5005, count: int = -1) -> None:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", port))
    print(f"listening on udp 127.0.0.1:{sock.getsockname()[1]}", flush=True)
    seen, warned = 0, False
    while count < 0 or seen < count:
        try:
            event = json.loads(sock.recv(65536))
        except ValueError:
            print("not an event line, skipped", file=sys.stderr)
            continue
        if event.get("protocol", 0) > PROTOCOL and not warned:
            print(f"protocol {event['protocol']} is newer than this listener ({PROTOCOL})", file=sys.stderr)
            warned = True
        text = describe(event)
        if text is not None:
            print(text, flush=True)
            seen += 1


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:3]))
