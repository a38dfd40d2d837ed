"""Where a live monitor's committed conclusions go: the sinks of `outbox`'s contract (an MQTT
broker, a webhook, an OPC UA server), each handed what every commit holds, and the command line's
options that name them.
"""

from __future__ import annotations

from ...errors import JmlgError
from ..sources.bus import credentials, secret

# each sink's options on the command line, the first naming it (its URL), the others going with it:
# flag -> argparse's keywords; and what the sink is, in messages
SINKS = {
    "--publish": ("the --publish broker", {
        "--publish": dict(metavar="URL", help="mqtt://HOST:PORT/PREFIX or mqtts://...: publish each row's state "
                          "(retained) on PREFIX/state and each alarm transition on PREFIX/alarm (PREFIX/UNIT/... for "
                          "a fleet's units), as JSON at QoS 1, once committed to the store"),
        "--publish-username": dict(metavar="NAME", help="user name at the --publish broker"),
        "--publish-password-env": dict(metavar="VAR", help="the environment variable that holds its password"),
        "--publish-password-file": dict(metavar="FILE", help="the file that holds its password (first line)"),
        "--publish-ca-file": dict(metavar="FILE", help="certificate authority of an mqtts:// --publish broker "
                                  "(default the system's)")}),
    "--notify": ("the --notify webhook", {
        "--notify": dict(metavar="URL", help="http(s) webhook: POST each alarm transition (raised, cleared, "
                         "acknowledged, shelved, unshelved) as JSON, retried with back-off, never holding the "
                         "diagnosis up"),
        "--notify-token-env": dict(metavar="VAR", help="the environment variable that holds a token sent as "
                                   "'Authorization: Bearer TOKEN'"),
        "--notify-token-file": dict(metavar="FILE", help="the file that holds that token (first line)")}),
    "--opcua-server": ("the --opcua-server", {
        "--opcua-server": dict(metavar="URL", help="opc.tcp://HOST:PORT/PATH: serve each plant's (or unit's) most "
                               "probable mode, every mode's probability and the alarm as OPC UA nodes, and each "
                               "alarm as an Alarms & Conditions OffNormalAlarm whose Acknowledge and shelving "
                               "methods act as the page's buttons do"),
        "--opcua-server-username": dict(metavar="NAME", help="the user name the --opcua-server lets in (default: "
                                        "anonymous clients)"),
        "--opcua-server-password-env": dict(metavar="VAR", help="the environment variable that holds that user's "
                                            "password"),
        "--opcua-server-password-file": dict(metavar="FILE", help="the file that holds that user's password (first "
                                             "line)"),
        "--opcua-server-security": dict(metavar="POLICY,MODE", help="the --opcua-server's only endpoint, e.g. "
                                        "Basic256Sha256,SignAndEncrypt (default None: no security)"),
        "--opcua-server-certificate": dict(metavar="FILE", help="the --opcua-server's certificate"),
        "--opcua-server-private-key": dict(metavar="FILE", help="the --opcua-server's private key")}),
}

COMMAND_LINE = {flag: keywords for _, options in SINKS.values() for flag, keywords in options.items()}


def open_sinks(given: dict, *, client_id: str, store: str, password: str | None, units=None,
               cluster: str | None = None) -> list:
    """The sinks the command line names, not yet started: `given` holds its options' values by their
    names (SINKS' flags, as argparse stores them: publish_username, ...). An option that goes with a
    sink not named is refused, as is a sink with --cluster. The publisher's MQTT client id is
    `client_id`-publish; the OPC UA server reads `store` with `password`."""
    value = {flag: given.get(flag[2:].replace("-", "_")) for _, options in SINKS.values() for flag in options}
    for sink, (what, options) in SINKS.items():
        for option in list(options)[1:]:
            if value[option] is not None and value[sink] is None:
                raise JmlgError(f"{option} is for {what}: give {sink}")
    named = [sink for sink in SINKS if value[sink]]
    if named and cluster:
        raise JmlgError(f"{named[0]} is not yet taken with --cluster; run the fleet's monitor without it")
    sinks = []
    if value["--publish"] is not None:
        from .publish import MqttPublisher

        sinks.append(MqttPublisher(value["--publish"], client_id=f"{client_id}-publish", credentials=credentials(
            value["--publish-username"], value["--publish-password-env"], value["--publish-password-file"],
            "--publish-"), ca_file=value["--publish-ca-file"]))
    if value["--notify"] is not None:
        from .webhook import Webhook

        sinks.append(Webhook(value["--notify"], token=secret("notify-token", value["--notify-token-env"],
                                                              value["--notify-token-file"])))
    if value["--opcua-server"] is not None:
        from .opcua_server import OpcuaServer

        sinks.append(OpcuaServer(value["--opcua-server"], store=store, password=password, units=units,
                                 credentials=credentials(value["--opcua-server-username"],
                                                         value["--opcua-server-password-env"],
                                                         value["--opcua-server-password-file"], "--opcua-server-"),
                                 security=value["--opcua-server-security"],
                                 certificate=value["--opcua-server-certificate"],
                                 private_key=value["--opcua-server-private-key"]))
    return sinks
