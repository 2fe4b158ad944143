"""``flatlab push``: the real CLI uploads a tiny collected dataset to a fake hub on 127.0.0.1
(``HF_ENDPOINT``), and ``LeRobotDataset(repo_id)`` downloads it back from there.

The fake hub (stdlib ``http.server``, in a thread) speaks the part of the hub's HTTP API that
``huggingface_hub`` 1.x uses for create_repo / create_branch / preupload / commit / tags / refs /
tree / revision info / resolve; every upload is answered "regular" (content inline, no LFS/Xet)."""

import base64
import hashlib
import json
import os
import re
import subprocess
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pytest
from test_collect import write_recipe  # tests/ is on sys.path under pytest

from flatlab_lerobot.collect.collector import collect
from flatlab_lerobot.collect.recipe import load_recipe

BIN = Path(sys.executable).parent
TOKEN = "hf_fake_token"
REPO = "flatlab-test/tiny_push"


# ------------------------------------------------------------------------------------ fake hub
def _git_oid(data: bytes) -> str:
    return hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()


class FakeHub:
    """In-memory dataset repos: commits (sha -> {path: bytes}), branches and tags (name -> sha)."""

    def __init__(self):
        self.repos: dict[str, dict] = {}
        self.log: list[tuple[str, str]] = []
        self.auth: set[str] = set()
        self.lock = threading.Lock()
        self.server = ThreadingHTTPServer(("127.0.0.1", 0), self._handler())
        self.endpoint = f"http://127.0.0.1:{self.server.server_address[1]}"
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.server.shutdown()
        self.server.server_close()

    def _new_commit(self, repo: dict, files: dict, message: str) -> str:
        sha = hashlib.sha1(f"{len(repo['commits'])}:{message}:{sorted(files)}".encode()).hexdigest()
        repo["commits"][sha] = files
        return sha

    def resolve(self, repo: dict, rev: str) -> str | None:
        rev = unquote(rev)
        if rev in repo["branches"]:
            return repo["branches"][rev]
        if rev in repo["tags"]:
            return repo["tags"][rev]
        return rev if rev in repo["commits"] else None

    def files(self, repo_id: str, rev: str = "main") -> dict[str, bytes]:
        repo = self.repos[repo_id]
        return repo["commits"][self.resolve(repo, rev)]

    def _handler(self):
        hub = self

        class H(BaseHTTPRequestHandler):
            def log_message(self, *a):  # quiet
                pass

            def _send(self, code, body=b"", headers=None, head=False):
                if isinstance(body, (dict, list)):
                    body = json.dumps(body).encode()
                    headers = {"Content-Type": "application/json", **(headers or {})}
                self.send_response(code)
                for k, v in (headers or {}).items():
                    self.send_header(k, v)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                if not head:
                    self.wfile.write(body)

            def _err(self, code, msg, error_code=None):
                h = {"X-Error-Code": error_code, "X-Error-Message": msg} if error_code else {"X-Error-Message": msg}
                self._send(code, {"error": msg}, h)

            def _body(self) -> bytes:
                n = int(self.headers.get("Content-Length") or 0)
                return self.rfile.read(n) if n else b""

            def _route(self, method):
                url = urlsplit(self.path)
                path = url.path
                with hub.lock:
                    hub.log.append((method, path))
                    if self.headers.get("Authorization"):
                        hub.auth.add(self.headers["Authorization"])
                    if method == "POST" and path == "/api/repos/create":
                        return self._create_repo(json.loads(self._body() or b"{}"))
                    if method == "POST" and path == "/api/validate-yaml":
                        return self._send(200, {})
                    m = re.match(r"^/api/datasets/([^/]+/[^/]+)(?:/([a-z]+)(?:/(.*))?)?$", path)
                    if m:
                        return self._api(method, m.group(1), m.group(2), m.group(3) or "", url.query)
                    m = re.match(r"^/datasets/([^/]+/[^/]+)/resolve/([^/]+)/(.+)$", path)
                    if m and method in ("GET", "HEAD"):
                        return self._resolve(m.group(1), m.group(2), unquote(m.group(3)), head=method == "HEAD")
                    return self._err(404, f"fake hub: no route for {method} {path}")

            def do_GET(self):
                self._route("GET")

            def do_HEAD(self):
                self._route("HEAD")

            def do_POST(self):
                self._route("POST")

            def do_DELETE(self):
                self._route("DELETE")

            # ---------------------------------------------------------------- handlers
            def _create_repo(self, body):
                if self.headers.get("Authorization") != f"Bearer {TOKEN}":
                    return self._err(401, "Invalid credentials")
                assert body.get("type") == "dataset", body
                repo_id = f"{body['organization']}/{body['name']}" if body.get("organization") else body["name"]
                url = f"{hub.endpoint}/datasets/{repo_id}"
                if repo_id in hub.repos:  # the hub answers 409 with the url, which create_repo(exist_ok) returns
                    return self._send(409, {"error": "You already created this dataset repo", "url": url})
                repo = {"commits": {}, "branches": {}, "tags": {}, "private": bool(body.get("private"))}
                repo["branches"]["main"] = hub._new_commit(repo, {".gitattributes": b"*.mp4 filter=lfs\n"}, "init")
                hub.repos[repo_id] = repo
                return self._send(200, {"url": url, "name": repo_id})

            def _api(self, method, repo_id, action, rest, query):
                repo = hub.repos.get(repo_id)
                if repo is None:
                    return self._err(404, f"Repository {repo_id} not found", "RepoNotFound")
                if action is None and method == "GET":
                    return self._info(repo_id, repo, "main")
                if action == "revision" and method == "GET":
                    return self._info(repo_id, repo, rest)
                if action == "refs" and method == "GET":

                    def refs(d, kind):
                        return [{"name": n, "ref": f"refs/{kind}/{n}", "targetCommit": s} for n, s in d.items()]

                    return self._send(200, {"branches": refs(repo["branches"], "heads"),
                                            "tags": refs(repo["tags"], "tags"), "converts": []})  # fmt: skip
                if action == "tree" and method == "GET":
                    rev, _, sub = rest.partition("/")
                    sha = hub.resolve(repo, rev)
                    if sha is None:
                        return self._err(404, f"Invalid rev id: {rev}", "RevisionNotFound")
                    sub = unquote(sub)
                    files = repo["commits"][sha]
                    out = [{"type": "file", "path": p, "size": len(b), "oid": _git_oid(b)}
                           for p, b in sorted(files.items()) if not sub or p.startswith(sub.rstrip("/") + "/")]  # fmt: skip
                    return self._send(200, out)
                if self.headers.get("Authorization") != f"Bearer {TOKEN}":
                    return self._err(401, "Invalid credentials")
                if action == "preupload" and method == "POST":
                    body = json.loads(self._body())
                    return self._send(200, {"files": [{"path": f["path"], "uploadMode": "regular", "shouldIgnore": False}
                                                      for f in body["files"]]})  # fmt: skip
                if action == "commit" and method == "POST":
                    return self._commit(repo_id, repo, unquote(rest))
                if action == "branch" and method == "POST":
                    name = unquote(rest)
                    if name in repo["branches"]:
                        return self._err(409, "Reference already exists")
                    start = (json.loads(self._body() or b"{}")).get("startingPoint") or "main"
                    repo["branches"][name] = hub.resolve(repo, start)
                    return self._send(200, {})
                if action == "tag" and method == "POST":
                    body = json.loads(self._body())
                    sha = hub.resolve(repo, rest)
                    if sha is None:
                        return self._err(404, f"Invalid rev id: {rest}", "RevisionNotFound")
                    if body["tag"] in repo["tags"]:
                        return self._err(409, "Tag already exists")
                    repo["tags"][body["tag"]] = sha
                    return self._send(200, {})
                if action == "tag" and method == "DELETE":
                    tag = unquote(rest)
                    if tag not in repo["tags"]:
                        return self._err(404, f"Invalid rev id: {tag}", "RevisionNotFound")
                    del repo["tags"][tag]
                    return self._send(200, {})
                return self._err(404, f"fake hub: no route for {method} {action}/{rest}")

            def _info(self, repo_id, repo, rev):
                sha = hub.resolve(repo, rev)
                if sha is None:
                    return self._err(404, f"Invalid rev id: {rev}", "RevisionNotFound")
                files = repo["commits"][sha]
                return self._send(200, {"id": repo_id, "sha": sha, "private": repo["private"],
                                        "siblings": [{"rfilename": p} for p in sorted(files)]})  # fmt: skip

            def _commit(self, repo_id, repo, rev):
                if rev not in repo["branches"]:
                    return self._err(404, f"Invalid rev id: {rev}", "RevisionNotFound")
                files = dict(repo["commits"][repo["branches"][rev]])
                summary = ""
                for line in self._body().splitlines():
                    item = json.loads(line)
                    key, v = item["key"], item["value"]
                    if key == "header":
                        summary = v["summary"]
                    elif key == "file":
                        assert v["encoding"] == "base64"
                        files[v["path"]] = base64.b64decode(v["content"])
                    elif key == "deletedFile":
                        files.pop(v["path"], None)
                    else:
                        return self._err(400, f"fake hub: unsupported commit operation {key}")
                sha = hub._new_commit(repo, files, summary)
                repo["branches"][rev] = sha
                return self._send(200, {"commitUrl": f"{hub.endpoint}/datasets/{repo_id}/commit/{sha}",
                                        "commitOid": sha, "pullRequestUrl": None})  # fmt: skip

            def _resolve(self, repo_id, rev, path, head):
                repo = hub.repos.get(repo_id)
                if repo is None:
                    return self._err(404, "Repository not found", "RepoNotFound")
                sha = hub.resolve(repo, rev)
                if sha is None:
                    return self._err(404, f"Invalid rev id: {rev}", "RevisionNotFound")
                data = repo["commits"][sha].get(path)
                if data is None:
                    return self._err(404, f"Entry not found: {path}", "EntryNotFound")
                return self._send(200, data, {"X-Repo-Commit": sha, "ETag": f'"{_git_oid(data)}"'}, head=head)

        return H


# ------------------------------------------------------------------------------------ fixtures
@pytest.fixture(scope="module")
def tiny_root(tmp_path_factory):
    d = tmp_path_factory.mktemp("hub")
    recipe = load_recipe(write_recipe(d / "t.yaml", episodes=2, max_steps=12, modalities=["rgb", "ee_pose"]))
    collect(recipe, d / "out", progress=False, log=lambda *a: None)
    return d / "out" / "t"


@pytest.fixture
def hub():
    with FakeHub() as h:
        yield h


def flatlab_push(*args, endpoint=None, token=TOKEN, cwd=None, home=None):
    env = {k: v for k, v in os.environ.items() if k not in ("HF_HUB_OFFLINE", "HF_TOKEN", "HF_ENDPOINT")}
    env.update(HF_HUB_DISABLE_PROGRESS_BARS="1", HF_HUB_DISABLE_TELEMETRY="1")
    if home is not None:
        env["HF_HOME"] = str(home)  # no cached login of the machine's user
    if endpoint:
        env["HF_ENDPOINT"] = endpoint
    if token:
        env["HF_TOKEN"] = token
    return subprocess.run([str(BIN / "flatlab"), "push", *map(str, args)], check=False, capture_output=True,
                          text=True, timeout=120, env=env, cwd=cwd)  # fmt: skip


# ------------------------------------------------------------------------------------ tests
def test_push_uploads_files_card_and_version_tag(tiny_root, hub, tmp_path):
    t0 = time.perf_counter()
    r = flatlab_push("--root", tiny_root, "--repo-id", REPO, "--tags", "smoke", endpoint=hub.endpoint, home=tmp_path)
    wall = time.perf_counter() - t0
    assert r.returncode == 0, r.stdout + r.stderr
    assert f"Bearer {TOKEN}" in hub.auth
    files = hub.files(REPO)
    local = sorted(p.relative_to(tiny_root).as_posix() for p in tiny_root.rglob("*") if p.is_file())
    # every local file arrived byte-identical, except README.md which is the freshly rendered card
    for rel in local:
        assert rel in files, rel
        if rel != "README.md":
            assert files[rel] == (tiny_root / rel).read_bytes(), rel
    assert any(f.startswith("data/") and f.endswith(".parquet") for f in files)
    assert any(f.startswith("videos/observation.images.front/") and f.endswith(".mp4") for f in files)
    assert {"meta/info.json", "meta/flatlab.json", "meta/flatlab_episodes.jsonl", "meta/stats.json"} <= set(files)
    # tagged with the codebase version, on the commit that holds the data
    repo = hub.repos[REPO]
    assert repo["tags"] == {"v3.0": repo["branches"]["main"]}
    # the card: hub YAML header, object ids, episode counts, success rate, the target repo_id
    card = files["README.md"].decode()
    recs = [json.loads(x) for x in (tiny_root / "meta/flatlab_episodes.jsonl").read_text().splitlines()]
    n_ok = sum(r["success"] for r in recs)
    assert card.startswith("---\n") and "- LeRobot\n" in card and "- smoke\n" in card and "- robotics\n" in card
    assert "`ref_box`" in card and "| Box | reference | rigid | B |" in card
    assert f"| episodes attempted / saved / successful | 2 / 2 / {n_ok} |" in card
    assert f"| success rate (successful / attempted) | {100 * n_ok / 2:.1f}% ({n_ok} / 2) |" in card
    assert f'LeRobotDataset("{REPO}"' in card and f"--dataset.repo_id={REPO}" in card
    reasons = [r["failure_reason"] for r in recs if not r["success"]]
    for reason in set(reasons):  # the failure-reason histogram
        assert f"| {reason} | {reasons.count(reason)} |" in card, reason
    assert "## Failure reasons" in card and "```yaml\nname: t\n" in card and '"total_episodes": 2' in card
    from huggingface_hub import DatasetCard

    assert DatasetCard(card).data.tags[:2] == ["LeRobot", "FlatLab"]
    print(f"push of {len(files)} files: {wall:.1f} s")


def test_push_again_to_branch_removes_stale_files(tiny_root, hub, tmp_path):
    assert flatlab_push("--root", tiny_root, "--repo-id", REPO, endpoint=hub.endpoint, home=tmp_path).returncode == 0
    repo = hub.repos[REPO]
    stale = "data/chunk-000/file-999.parquet"
    repo["commits"][repo["branches"]["main"]][stale] = b"from an older push"
    r = flatlab_push("--root", tiny_root, "--repo-id", REPO, "--no-videos", "--branch", "dev",
                     endpoint=hub.endpoint, home=tmp_path)  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    dev = hub.files(REPO, "dev")
    assert stale not in dev and "meta/info.json" in dev
    assert stale in hub.files(REPO, "main")  # main untouched
    assert repo["tags"]["v3.0"] == repo["branches"]["dev"]
    assert "1 stale removed" in r.stdout


@pytest.mark.slow
def test_lerobot_dataset_downloads_it_back(tiny_root, hub, tmp_path):
    r = flatlab_push("--root", tiny_root, "--repo-id", REPO, endpoint=hub.endpoint, home=tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    code = (
        "import json, flatlab_lerobot\n"
        "from lerobot.datasets.lerobot_dataset import LeRobotDataset\n"
        f"ds = LeRobotDataset({REPO!r}, video_backend='pyav')\n"
        "x = ds[0]\n"
        "print(json.dumps({'root': str(ds.root), 'episodes': ds.num_episodes, 'frames': ds.num_frames,\n"
        "  'revision': ds.revision, 'img': list(x['observation.images.front'].shape), 'object': x['object_id']}))\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("HF_HUB_OFFLINE", "HF_TOKEN")}
    env.update(HF_ENDPOINT=hub.endpoint, HF_HOME=str(tmp_path / "hf"), HF_LEROBOT_HOME=str(tmp_path / "lerobot"),
               HF_HUB_DISABLE_PROGRESS_BARS="1", HF_HUB_DISABLE_TELEMETRY="1")  # fmt: skip
    p = subprocess.run([sys.executable, "-c", code], check=False, capture_output=True, text=True, timeout=180, env=env)
    assert p.returncode == 0, p.stderr[-4000:]
    out = json.loads(p.stdout.strip().splitlines()[-1])
    info = json.loads((tiny_root / "meta/info.json").read_text())
    assert out["episodes"] == 2 and out["frames"] == info["total_frames"]
    assert out["revision"] == "v3.0" and out["img"] == [3, 32, 32] and out["object"] == "ref_box"
    assert str(tmp_path / "lerobot") in out["root"]


# ------------------------------------------------------------------------------------ bad input
def test_bad_root_is_a_clear_error(tiny_root, tmp_path):
    missing = tmp_path / "no_such_dataset"
    r = flatlab_push("--root", missing, "--repo-id", REPO, home=tmp_path)
    assert r.returncode == 2 and str(missing) in r.stderr and "no such folder" in r.stderr, r.stderr
    not_lerobot = tmp_path / "empty"
    not_lerobot.mkdir()
    r = flatlab_push("--root", not_lerobot, "--repo-id", REPO, home=tmp_path)
    assert r.returncode == 2 and str(not_lerobot / "meta/info.json") in r.stderr, r.stderr
    staging = tmp_path / ".t.staging"
    staging.mkdir()
    r = flatlab_push("--root", staging, "--repo-id", REPO, home=tmp_path)
    assert r.returncode == 2 and str(staging) in r.stderr and "half-written" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr


def test_inconsistent_dataset_and_bad_repo_id(tiny_root, tmp_path):
    import shutil

    broken = tmp_path / "t"
    shutil.copytree(tiny_root, broken)
    recs = (broken / "meta/flatlab_episodes.jsonl").read_text().splitlines()
    (broken / "meta/flatlab_episodes.jsonl").write_text(recs[0] + "\n")
    r = flatlab_push("--root", broken, "--repo-id", REPO, home=tmp_path)
    assert r.returncode == 2 and "field 'total_episodes'" in r.stderr and str(broken / "meta/info.json") in r.stderr
    r = flatlab_push("--root", tiny_root, "--repo-id", "not a repo id", home=tmp_path)
    assert r.returncode == 2 and "--repo-id 'not a repo id'" in r.stderr, r.stderr
    r = flatlab_push("--root", tiny_root, "--repo-id", REPO, token=None, home=tmp_path, endpoint="http://127.0.0.1:9")
    assert r.returncode == 2 and "no hub token" in r.stderr, r.stderr


def test_dry_run_writes_card_only(tiny_root, tmp_path):
    before = sorted((p.relative_to(tiny_root).as_posix(), p.stat().st_mtime_ns) for p in tiny_root.rglob("*"))
    out = tmp_path / "card.md"
    r = flatlab_push("--root", tiny_root, "--dry-run", "--card-out", out, home=tmp_path)
    assert r.returncode == 0, r.stderr
    card = out.read_text()
    assert "local/flatlab_t" in card and "`ref_box`" in card  # the recipe's repo_id by default
    assert "meta/info.json" in r.stderr and "README.md card" in r.stderr
    assert before == sorted((p.relative_to(tiny_root).as_posix(), p.stat().st_mtime_ns) for p in tiny_root.rglob("*"))
