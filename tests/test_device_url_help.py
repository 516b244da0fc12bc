"""A tcp:// device URL without a port takes the SDH-2's port: the help texts that ask for a device URL and
the guide's list of URL forms say so, quoting the transport's own default (a stranger met it nowhere)."""

from __future__ import annotations

import argparse

from firmware_io.transports import validate_url
from firmware_io.transports.tcp import DEFAULT_PORT, URL_FORM, TcpTransport
from tests.conftest import ROOT


def _help(module) -> str:
    parser = argparse.ArgumentParser()
    module.add_arguments(parser)
    return parser.format_help()


def test_a_tcp_url_without_a_port_takes_the_default_port():
    assert TcpTransport.url_settings(validate_url("tcp://127.0.0.1"), {})["port"] == DEFAULT_PORT
    assert f"port {DEFAULT_PORT}" in URL_FORM and "[:PORT]" in URL_FORM


def test_the_device_help_texts_say_the_default_port():
    from firmware_io.commands import dump_cli
    from trainer.commands import record_cli

    for module in (record_cli, dump_cli):
        text = " ".join(_help(module).split())  # argparse wraps lines
        assert URL_FORM in text, module.__name__


def test_the_guides_list_of_device_urls_says_the_default_port():
    guide = (ROOT / "docs" / "GUIDE.md").read_text()
    urls = " ".join(guide[guide.index("Device URLs:"):].split("\n\n")[0].split())
    assert "`tcp://HOST[:PORT]`" in urls and f"port {DEFAULT_PORT} when the URL names none" in urls, urls
