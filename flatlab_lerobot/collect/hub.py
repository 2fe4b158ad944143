"""``flatlab push``: upload a collected dataset to the Hugging Face hub with a generated dataset card.

    flatlab push --root outputs/datasets/tiny_rigid --repo-id <user>/flatlab_tiny_rigid [--private]
                 [--branch B] [--tags t1 t2] [--no-videos] [--dry-run] [--card-out card.md] [--token T]

What it does, in the order lerobot's ``LeRobotDataset.push_to_hub`` does it:

1. checks that ``--root`` is a *committed* ``flatlab collect`` dataset (``meta/info.json``,
   ``meta/flatlab.json``, ``meta/flatlab_episodes.jsonl`` agree; not a ``.<name>.staging`` folder);
2. renders the dataset card (``README.md``: objects with category / split / strategy, splits,
   modalities and features, cameras, fps, episode counts, success rate, failure reasons, recipe,
   how to load and train) for the target ``repo_id``;
3. ``create_repo`` (dataset, ``exist_ok``), ``create_branch`` when ``--branch`` is given;
4. ONE commit holding ``data/``, ``meta/``, ``videos/`` (unless ``--no-videos``) and the card, which
   also deletes files of an earlier push that this version no longer has, so the hub copy is
   never visible half-uploaded or without its card;
5. tags that commit with the dataset's codebase version (``v3.0``), which is the revision
   ``LeRobotDataset(repo_id)`` downloads.

lerobot's own ``push_to_hub`` is not called because it always replaces ``README.md`` by lerobot's
generic card and validates it against a hard-coded ``https://huggingface.co`` URL (ignoring
``HF_ENDPOINT``); the card is checked locally instead (its YAML header is parsed by
``huggingface_hub.DatasetCard``).  The token comes from ``--token``, ``HF_TOKEN`` or the cached
``hf auth login``; ``HF_ENDPOINT`` selects another hub.  Exit codes: 0 done, 1 upload failed,
2 bad input (the message names the path or field).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from dataclasses import dataclass
from pathlib import Path

from flatlab_lerobot.atomic import write_text
from flatlab_lerobot.collect.store import EPISODES_JSONL, META_JSON, READY

INFO_JSON = "meta/info.json"
_INFO_FIELDS = ("codebase_version", "fps", "features", "total_episodes", "total_frames")
# the dataset folders that are mirrored: files of an earlier push under these that this version lacks are deleted
_MIRRORED = ("data/", "meta/", "videos/")


class PushError(ValueError):
    """Bad input for ``flatlab push``; the message names the path or the field."""


@dataclass
class LocalDataset:
    root: Path
    info: dict
    meta: dict
    records: list[dict]
    recipe: object  # flatlab_lerobot.collect.recipe.Recipe

    @property
    def version(self) -> str:
        return self.info["codebase_version"]


# ---------------------------------------------------------------------------------- checks
def _read_json(path: Path, what: str) -> dict:
    if not path.is_file():
        raise PushError(f"{path}: missing; {what}")
    try:
        d = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise PushError(f"{path}: invalid JSON: {exc}") from exc
    if not isinstance(d, dict):
        raise PushError(f"{path}: expected a JSON object, got {type(d).__name__}")
    return d


def load_local(root: str | Path) -> LocalDataset:
    """The committed FlatLab dataset at ``root``, checked; :class:`PushError` naming the path if not."""
    from flatlab_lerobot.collect.recipe import RecipeError, recipe_from_dict

    root = Path(root)
    if not root.exists():
        raise PushError(f"{root}: no such folder (expected a collected dataset, e.g. outputs/datasets/<name>)")
    if not root.is_dir():
        raise PushError(f"{root}: not a folder")
    name = root.name
    if name.startswith(".") and name.endswith((".staging", ".old")):
        committed = root.parent / name[1:].rsplit(".", 1)[0]
        raise PushError(
            f"{root}: a half-written `flatlab collect` {name.rsplit('.', 1)[1]} folder, not a committed dataset; "
            f"re-run `flatlab collect` with the same recipe to recover it, then push {committed}"
        )
    if (root / READY).exists():
        raise PushError(
            f"{root}: an interrupted `flatlab collect` commit ({READY} present); re-run `flatlab collect` "
            "with the same recipe to complete it, then push"
        )
    info = _read_json(root / INFO_JSON, f"{root} is not a LeRobotDataset")
    for fld in _INFO_FIELDS:
        if fld not in info:
            raise PushError(f"{root / INFO_JSON}: field '{fld}' is missing")
    meta = _read_json(
        root / META_JSON,
        f"{root} is not a `flatlab collect` dataset (push a plain LeRobotDataset with LeRobotDataset.push_to_hub)",
    )
    if not isinstance(meta.get("recipe"), dict):
        raise PushError(f"{root / META_JSON}: field 'recipe' is missing or not a mapping")
    ep_path = root / EPISODES_JSONL
    if not ep_path.is_file():
        raise PushError(f"{ep_path}: missing; {root} is not a complete `flatlab collect` dataset")
    records = []
    for i, line in enumerate(ep_path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            r = json.loads(line)
        except json.JSONDecodeError as exc:
            raise PushError(f"{ep_path}: line {i}: invalid JSON: {exc}") from exc
        missing = [k for k in ("object_id", "strategy", "success", "seed", "num_frames") if k not in r]
        if missing or "dataset_episode_index" not in r:
            raise PushError(f"{ep_path}: line {i}: field '{(missing or ['dataset_episode_index'])[0]}' is missing")
        records.append(r)
    saved = sum(1 for r in records if r["dataset_episode_index"] is not None)
    if saved != info["total_episodes"]:
        raise PushError(
            f"{root / INFO_JSON}: field 'total_episodes' is {info['total_episodes']} but {ep_path} lists {saved} "
            "saved episodes; the folder was modified outside `flatlab collect`"
        )
    if info["total_episodes"]:
        if not any((root / "data").rglob("*.parquet")):
            raise PushError(f"{root / 'data'}: no parquet file, but {INFO_JSON} lists {saved} episodes")
        if not any((root / "meta" / "episodes").rglob("*.parquet")):
            raise PushError(f"{root / 'meta' / 'episodes'}: no parquet file, but {INFO_JSON} lists {saved} episodes")
        for key, ft in info["features"].items():
            if ft.get("dtype") == "video" and not any((root / "videos" / key).rglob("*.mp4")):
                raise PushError(f"{root / 'videos' / key}: no video file for the video feature '{key}'")
    # the recipe, back from its saved form (empty / null fields take their defaults)
    raw = {k: v for k, v in meta["recipe"].items() if v not in ("", None)}
    try:
        recipe = recipe_from_dict(raw, f"{root / META_JSON} (recipe)")
    except RecipeError as exc:
        raise PushError(str(exc)) from exc
    return LocalDataset(root, info, meta, records, recipe)


def upload_files(root: Path, push_videos: bool = True) -> list[str]:
    """Repo paths to upload (posix, sorted): everything but hidden files, lerobot's ``images/`` scratch
    folder, the local ``README.md`` (replaced by the fresh card) and, with ``push_videos=False``, ``videos/``."""
    out = []
    for p in sorted(root.rglob("*")):
        rel = p.relative_to(root)
        if not p.is_file() or any(part.startswith(".") for part in rel.parts):
            continue
        top = rel.parts[0]
        if top == "images" or rel.as_posix() == "README.md" or (top == "videos" and not push_videos):
            continue
        out.append(rel.as_posix())
    return out


def make_card(ds: LocalDataset, repo_id: str, tags=(), license: str = "apache-2.0") -> str:
    """The dataset card for ``repo_id``; its YAML header is checked the way the hub parses it."""
    from huggingface_hub import DatasetCard

    from flatlab_lerobot.collect.card import render_card

    card = render_card(ds.recipe, ds.meta, ds.records, repo_id=repo_id, tags=list(tags), license=license, info=ds.info)
    try:
        DatasetCard(card)
    except ValueError as exc:
        raise PushError(f"the generated dataset card has an invalid YAML header: {exc}") from exc
    return card


def _check_repo_id(repo_id: str) -> str:
    from huggingface_hub.utils import HFValidationError, validate_repo_id

    try:
        validate_repo_id(repo_id)
    except HFValidationError as exc:
        raise PushError(f"--repo-id {repo_id!r}: {exc}") from exc
    if repo_id.count("/") != 1:
        raise PushError(f"--repo-id {repo_id!r}: must look like 'user/name' or 'org/name'")
    return repo_id


# ---------------------------------------------------------------------------------- upload
def push(
    ds: LocalDataset,
    repo_id: str,
    card: str,
    *,
    token: str | None = None,
    private: bool = False,
    branch: str | None = None,
    push_videos: bool = True,
    commit_message: str | None = None,
    log=print,
) -> dict:
    """create_repo -> (create_branch) -> one commit (files + card, stale files deleted) -> version tag."""
    from huggingface_hub import CommitOperationAdd, CommitOperationDelete, HfApi, constants
    from huggingface_hub.errors import RepositoryNotFoundError, RevisionNotFoundError

    api = HfApi(token=token)
    repo_url = api.create_repo(repo_id, repo_type="dataset", private=True if private else None, exist_ok=True)
    if branch:
        api.create_branch(repo_id, branch=branch, repo_type="dataset", exist_ok=True)
    files = upload_files(ds.root, push_videos)
    ops: list = [CommitOperationAdd(path_in_repo=f, path_or_fileobj=str(ds.root / f)) for f in files]
    ops.append(CommitOperationAdd(path_in_repo="README.md", path_or_fileobj=card.encode()))
    try:
        remote = set(api.list_repo_files(repo_id, repo_type="dataset", revision=branch))
    except (RepositoryNotFoundError, RevisionNotFoundError):
        remote = set()
    mirrored = tuple(m for m in _MIRRORED if push_videos or m != "videos/")
    stale = sorted(f for f in remote - set(files) if f.startswith(mirrored))
    ops += [CommitOperationDelete(path_in_repo=f) for f in stale]
    n_ok = sum(1 for r in ds.records if r["success"])
    message = commit_message or (
        f"flatlab push: {ds.recipe.name} ({ds.info['total_episodes']} episodes, {n_ok}/{len(ds.records)} successful)"
    )
    commit = api.create_commit(repo_id, ops, commit_message=message, repo_type="dataset", revision=branch)
    with contextlib.suppress(RevisionNotFoundError):
        api.delete_tag(repo_id, tag=ds.version, repo_type="dataset")
    api.create_tag(repo_id, tag=ds.version, revision=commit.oid, repo_type="dataset")
    nbytes = sum((ds.root / f).stat().st_size for f in files) + len(card.encode())
    return {
        "repo_id": repo_id,
        "url": str(repo_url),
        "endpoint": constants.ENDPOINT,
        "branch": branch or "main",
        "commit": commit.oid,
        "tag": ds.version,
        "files": len(files) + 1,
        "deleted": len(stale),
        "bytes": nbytes,
    }


# ---------------------------------------------------------------------------------- CLI
def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="flatlab push",
        description="Upload a `flatlab collect` dataset (data, meta, videos and a generated dataset card) to the "
        "Hugging Face hub and tag it with its LeRobotDataset codebase version, so that "
        "LeRobotDataset(repo_id) downloads it. HF_ENDPOINT selects another hub.",
    )
    ap.add_argument("--root", type=Path, required=True, help="the collected dataset, e.g. outputs/datasets/tiny_rigid")
    ap.add_argument("--repo-id", help="hub dataset repo 'user/name' (required unless --dry-run; default there: the "
                    "recipe's repo_id)")  # fmt: skip
    ap.add_argument("--private", action="store_true", help="create the repo private (an existing repo keeps its own)")
    ap.add_argument("--branch", help="push to this branch (created if missing; default: main)")
    ap.add_argument("--tags", nargs="*", default=[], help="extra dataset-card tags (LeRobot, FlatLab, ... always)")
    ap.add_argument("--license", default="apache-2.0", help="dataset-card license id (default: apache-2.0)")
    ap.add_argument(
        "--no-videos", action="store_true", help="do not upload videos/ (the dataset then lacks its camera streams)"
    )
    ap.add_argument(
        "--dry-run", action="store_true", help="check the dataset and print the card and the file list; upload nothing"
    )
    ap.add_argument("--card-out", type=Path, help="also write the card to this file")
    ap.add_argument("--token", help="hub token (default: $HF_TOKEN, then the cached `hf auth login`)")
    ap.add_argument("--message", help="commit message")
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)

    def fail(msg: str, code: int = 2) -> int:
        print(f"flatlab push: error: {msg}", file=sys.stderr)
        return code

    try:
        ds = load_local(args.root)
        if args.repo_id is None and not args.dry_run:
            raise PushError("--repo-id is required to upload (e.g. --repo-id <your-user>/" + ds.recipe.name + ")")
        repo_id = _check_repo_id(args.repo_id or ds.recipe.repo_id)
        card = make_card(ds, repo_id, args.tags, args.license)
    except PushError as exc:
        return fail(str(exc))
    staging = args.root.parent / f".{args.root.name}.staging"
    if staging.exists():
        print(f"[push] note: {staging} exists (a collection is running or was interrupted); "
              "pushing the last committed version", file=sys.stderr)  # fmt: skip
    if args.card_out:
        write_text(args.card_out, card)
    files = upload_files(ds.root, not args.no_videos)
    if args.dry_run:
        size = sum((ds.root / f).stat().st_size for f in files)
        print(f"[push] dry run: {len(files)} files ({size / 1e6:.2f} MB) + README.md card -> dataset {repo_id}",
              file=sys.stderr)  # fmt: skip
        for f in files:
            print(f"[push]   {f}", file=sys.stderr)
        if not args.card_out:
            sys.stdout.write(card)
        return 0

    from huggingface_hub import constants, get_token

    if constants.HF_HUB_OFFLINE:
        return fail("HF_HUB_OFFLINE is set: unset it to upload")
    token = args.token or get_token()
    if not token:
        return fail("no hub token: pass --token, set HF_TOKEN, or run `hf auth login`")
    print(f"[push] {ds.root} -> dataset {repo_id} (branch {args.branch or 'main'}) at {constants.ENDPOINT}")
    try:
        res = push(ds, repo_id, card, token=token, private=args.private, branch=args.branch,
                   push_videos=not args.no_videos, commit_message=args.message)  # fmt: skip
    except Exception as exc:  # noqa: BLE001 -- any hub / network failure is reported, not a traceback
        return fail(f"upload of {ds.root} to {repo_id} at {constants.ENDPOINT} failed: {type(exc).__name__}: {exc}", 1)
    print(f"[push] {res['files']} files ({res['bytes'] / 1e6:.2f} MB, card included), {res['deleted']} stale removed; "
          f"commit {res['commit']}, tag {res['tag']}")  # fmt: skip
    print(f"[push] {res['url']}")
    print(f'[push] load it: LeRobotDataset("{repo_id}")')
    return 0


if __name__ == "__main__":
    sys.exit(main())
