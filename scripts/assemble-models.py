#!/usr/bin/env python3
"""Assemble one models folder from the folders a training chain wrote.

Usage: scripts/assemble-models.py OUT DIR... [--rename OLD=NEW]...

OUT gets a copy of every weights file (and its loss CSV) that the DIRs' manifests name, and one
manifest.json: the union of their `models` (a later DIR wins), and the refiners, decodings,
temperatures, voting and training statistics of the first DIR that has them. Every recorded
command has each OLD path prefix replaced by NEW, so that provenance reads as a user types it
from the repository (e.g. --rename ../data/v4/models-b=models-v4 --rename ../data/=data/).
Files are written to a temporary name and renamed, the manifest last.
"""
import json
import os
import shutil
import sys


def rewrite(value, renames):
    if isinstance(value, dict):
        return {k: (rewrite_cmd(v, renames) if k.endswith("command") and isinstance(v, str)
                    else rewrite(v, renames)) for k, v in value.items()}
    if isinstance(value, list):
        return [rewrite(v, renames) for v in value]
    return value


def rewrite_cmd(cmd, renames):
    words = []
    for w in cmd.split(" "):
        for old, new in renames:
            if w.startswith(old):
                w = new + w[len(old):]
                break
        words.append(w)
    return " ".join(words)


def copy_atomic(src, dst):
    tmp = dst + ".tmp"
    shutil.copyfile(src, tmp)
    os.replace(tmp, dst)


def main(argv):
    renames, rest = [], []
    it = iter(argv)
    for a in it:
        if a == "--rename":
            old, _, new = next(it).partition("=")
            renames.append((old, new))
        else:
            rest.append(a)
    if len(rest) < 2:
        sys.exit(__doc__)
    out, dirs = rest[0], rest[1:]
    os.makedirs(out, exist_ok=True)
    merged = None
    for d in dirs:
        with open(os.path.join(d, "manifest.json")) as f:
            m = json.load(f)
        if merged is None:
            merged = m
        else:
            merged["models"].update(m["models"])
            for k, v in m.items():
                if k != "models" and v and not merged.get(k):
                    merged[k] = v
        entries = [*m["models"].values(), m.get("refiner"), m.get("refiner_notrace")]
        for e in filter(None, entries):
            src = os.path.join(d, e["file"])
            copy_atomic(src, os.path.join(out, e["file"]))
            csv = src.replace(".safetensors", ".loss.csv")
            if os.path.isfile(csv):
                copy_atomic(csv, os.path.join(out, os.path.basename(csv)))
    merged = rewrite(merged, renames)
    tmp = os.path.join(out, "manifest.json.tmp")
    with open(tmp, "w") as f:
        json.dump(merged, f, indent=2)
        f.write("\n")
    os.replace(tmp, os.path.join(out, "manifest.json"))
    print(out, sorted(merged["models"]))


if __name__ == "__main__":
    main(sys.argv[1:])
