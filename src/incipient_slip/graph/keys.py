"""`slip keys list|rotate|init`: the CURVE keys and permissions of a graph over tcp (security.py).

The keystore is `<graph dir>/keys/` or `$SLIP_KEYSTORE`; see docs/graph.md, "Keys and permissions".
"""
from __future__ import annotations

import json
import os

from incipient_slip.errors import UsageError
from incipient_slip.graph import discovery

# security (zmq) and the launch are imported by the commands that use them: registering these
# commands must not load zmq

__all__ = ["register", "cmd_keys_list", "cmd_keys_rotate", "cmd_keys_init"]


def _store(args):
    from incipient_slip.graph import security
    return security.keystore(discovery.graph_dir(getattr(args, "graph", None)))


def cmd_keys_list(args) -> int:
    """Each identity of the keystore: its public key, whether its secret is here, and what the
    permissions file lets it publish and subscribe."""
    from incipient_slip.graph import security
    store = _store(args)
    path = store / security.PERMISSIONS_FILE
    allowed = security._read_permissions(path)["nodes"] if path.exists() else {}
    names = sorted({p.stem for p in store.glob("*.key")} | {p.name[:-len(".key_secret")]
                                                           for p in store.glob("*.key_secret")} | set(allowed))
    rows = []
    for name in names:
        cert = store / f"{name}.key"
        key = security._public_key(cert) if cert.exists() else None
        entry = allowed.get(name)
        secret = store / f"{name}.key_secret"
        rows.append({"identity": name, "key": key.decode() if key else None,
                     "secret": f"{os.stat(secret).st_mode & 0o777:o}" if secret.exists() else None,
                     "publish": entry["publish"] if entry else None,
                     "subscribe": entry["subscribe"] if entry else None,
                     "permitted_key": None if entry is None else entry["key"] == (key.decode() if key else None)})
    if args.json:
        print(json.dumps({"keystore": str(store), "permissions": str(path) if path.exists() else None,
                          "identities": rows}))
        return 0
    print(f"keystore {store}" + (f", permissions {path}" if path.exists() else ", no permissions file "
                                 "(every key of the keystore is admitted, for every topic)"))
    for r in rows:
        state = ("secret here (mode " + r["secret"] + ")") if r["secret"] else "public only"
        if r["publish"] is None and path.exists():
            state += "; NOT in the permissions file: refused"
        elif r["permitted_key"] is False:
            state += "; the permissions file holds another key: refused"
        print(f"{r['identity']:<20} {r['key'] or '-':<40}  {state}")
        if r["publish"] is not None:
            print(f"{'':<20} publish {', '.join(r['publish']) or '(nothing)'}; "
                  f"subscribe {', '.join(r['subscribe']) or '(nothing)'}")
    return 0


def cmd_keys_rotate(args) -> int:
    """Gives each NAME a new key pair (and the permissions file its new public key)."""
    from incipient_slip.graph import security
    store = _store(args)
    for name in args.names:
        if discovery.safe_name(name) != name:
            raise UsageError(f"identity {name!r}: use letters, digits, '_', '.', '-'")
        old, new = security.rotate(store, name)
        print(f"{name}: {old.decode() if old else '(no key)'} -> {new.decode()}")
    print("Running nodes re-read the keystore within a second: they refuse the old key from now on "
          "and reconnect to these identities pinning the new one. A running process that holds an "
          "old key is cut off (it says so) until it is restarted; copy the keystore again to the "
          "other hosts of a multi-host graph.")
    return 0


def cmd_keys_init(args) -> int:
    """Writes the permissions file of a launch (and every node's pair) without starting it: the
    keystore to copy to the hosts of a multi-host graph."""
    from incipient_slip.graph import security
    from incipient_slip.graph.launch import LaunchError, _split_cli_args, load

    try:
        desc = load(args.launch, _split_cli_args(args.args))
    except LaunchError as exc:
        raise UsageError(str(exc)) from None
    path = security.write_permissions(_store(args), desc.topology.permissions(), f"slip keys init {desc.file}")
    print(f"wrote {path}: {', '.join(sorted(desc.topology.permissions()))}")
    return 0


_HELP = "the per-node CURVE keys and the permissions file of a graph over tcp"
_DESCRIPTION = ("SLIP_TRANSPORT=tcp gives every node a CURVE key pair in the graph's keystore "
                "(<graph dir>/keys, or $SLIP_KEYSTORE) and enforces the permissions file a launch "
                "writes there. See docs/graph.md, 'Keys and permissions'.")
# (tool, help, its arguments (name or flag, add_argument keywords), handler)
_TOOLS = (
    ("list", "identities, public keys and permissions",
     [("--json", dict(action="store_true", help="one JSON object"))], cmd_keys_list),
    ("rotate", "give identities new key pairs (running nodes refuse the old ones at once; a node "
     "holding one must be restarted)",
     [("names", dict(nargs="+", metavar="NAME", help="a node name, or slip / slip-force (the tools)"))],
     cmd_keys_rotate),
    ("init", "write a launch's keys and permissions file without starting it (to copy the keystore "
     "to other hosts)",
     [("launch", dict(help="launch file: a path, or a name in launch/")),
      ("args", dict(nargs="*", metavar="name:=value", help="launch argument values"))], cmd_keys_init),
)


def register(subparsers) -> None:
    """Adds `slip keys ...`."""
    from incipient_slip.graph.tools import _graph_option, _guard, command_group
    graph = _graph_option()
    ksub = command_group(subparsers, "keys", help=_HELP, description=_DESCRIPTION)
    for tool, text, arguments, handler in _TOOLS:
        p = ksub.add_parser(tool, parents=[graph], help=text)
        for name, options in arguments:
            p.add_argument(name, **options)
        p.set_defaults(func=_guard(handler))
