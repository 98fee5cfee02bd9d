"""`evstream stages`: every registered stage and framer, with its parameters, units and defaults."""

from __future__ import annotations

import json

from .. import api


def cmd_stages(args) -> int:
    entries = api.catalogue(args.role)
    if args.json:
        print(json.dumps(entries, default=str))
        return 0
    for role in ("stage", "framer"):
        shown = [e for e in entries if e["role"] == role]
        if not shown:
            continue
        print({"stage": "stages (--denoise NAME --set PARAM=VALUE, or [[stage]] kind = NAME in a pipeline TOML)",
               "framer": "framers (--framer NAME and its flags, or [framer] kind = NAME)"}[role])
        for e in shown:
            print(f"  {e['kind']:<12} {e['summary']}")
            for p in e["parameters"]:
                default = "auto" if p["default"] is None else json.dumps(p["default"])
                unit = f" {p['unit']}" if p["unit"] else ""
                print(f"      {p['name']} = {default}{unit}  ({p['type']})")
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("stages", help="list every stage and framer with its parameters, units and defaults")
    p.add_argument("role", nargs="?", choices=["stage", "framer"], help="only stages or only framers")
    p.add_argument("--json", action="store_true", help="one JSON list")
    p.set_defaults(func=cmd_stages)
