"""A local test double of the Hugging Face Hub HTTP API (stdlib only), for pushes and downloads without the network.

Uploads: the requests huggingface_hub 1.33 makes for `create_repo` (with `visibility`), `create_branch`,
`create_tag`, `delete_tag`, `list_repo_refs`, `repo_info` and `create_commit` over the legacy LFS protocol
(preupload, LFS batch + basic upload + verify, the ndjson commit, `validate-yaml` for README.md), which is
everything `LeRobotDataset.push_to_hub` and `HfApi.upload_folder` use. There is no Xet storage: a client with
hf_xet installed must run with `HF_HUB_DISABLE_XET=1` (otherwise it uploads through a Xet CAS server).

Also `GET /api/agent-harnesses` (an empty registry), which huggingface_hub 1.x reads unless telemetry is off.

Downloads: `repo_info` (`sha`), the tree listing (`/api/{type}s/{id}/tree/{rev}[/{path}]`, recursive or not,
paginated with a `Link` header) and `HEAD`/`GET` on `/{datasets/}{id}/resolve/{rev}/{path}` (`X-Repo-Commit`,
`ETag`, `X-Linked-Etag`/`X-Linked-Size` for LFS files, byte ranges; no `X-Xet-Hash`, so files come over plain
HTTP), which is what `snapshot_download`, `hf_hub_download` and `LeRobotDataset(repo_id)` use. LFS files are
served directly (the real hub redirects them to a CDN). Unknown repos, revisions and files get the hub's 404s
(`X-Error-Code: RepoNotFound` / `RevisionNotFound` / `EntryNotFound` and `{"error": ...}`); a private repo is
"not found" without the token.

The routes and payloads follow `huggingface_hub/hf_api.py`, `_commit_api.py`, `lfs.py`, `file_download.py` and
`_snapshot_download.py`. State is kept in memory and is readable by tests: repos with their private flag,
branches, tags, commits (full file snapshots, exact bytes, which paths are LFS) and the list of files that
arrived. Requests it does not know are answered 501 and recorded in `unknown`.

Point a process at it with `HF_ENDPOINT=<double.url>` (set before huggingface_hub is imported).
"""

from __future__ import annotations

import base64
import hashlib
import json
import re
import threading
import time
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import parse_qs, quote, unquote, urlencode, urlsplit

TYPE_PREFIX = {"model": "", "dataset": "datasets/", "space": "spaces/"}
LFS_SUFFIXES = (
    ".parquet",
    ".mp4",
    ".arrow",
    ".bin",
    ".safetensors",
    ".pt",
    ".pth",
    ".npy",
    ".npz",
    ".zip",
    ".gz",
    ".tar",
    ".png",
    ".jpg",
    ".jpeg",
    ".h5",
    ".pkl",
    ".ckpt",
    ".onnx",
    ".msgpack",
)
REGULAR_MAX_BYTES = 10 * 1024 * 1024
INITIAL_GITATTRIBUTES = b"".join(f"*{s} filter=lfs diff=lfs merge=lfs -text\n".encode() for s in LFS_SUFFIXES)


def git_blob_oid(data: bytes) -> str:
    return hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()


def lfs_pointer(data: bytes) -> bytes:
    """The git-lfs pointer file git stores in place of an LFS file (its blob oid is the file's git oid)."""
    return (
        f"version https://git-lfs.github.com/spec/v1\noid sha256:{hashlib.sha256(data).hexdigest()}\n"
        f"size {len(data)}\n"
    ).encode()


def git_tree_oid(entries: dict[str, tuple[str, str]]) -> str:
    """Git's tree object id from {name: (mode, hex oid)} (directories sort as if named `name/`)."""

    def key(name: str) -> bytes:
        return (name + "/" if entries[name][0] == "40000" else name).encode()

    body = b"".join(
        f"{entries[n][0]} {n}".encode() + b"\0" + bytes.fromhex(entries[n][1])
        for n in sorted(entries, key=key)
    )
    return hashlib.sha1(b"tree %d\0" % len(body) + body).hexdigest()


@dataclass
class Upload:
    """One file that arrived in a commit."""

    path: str
    data: bytes
    lfs: bool
    revision: str
    commit: str


@dataclass
class Repo:
    repo_type: str
    repo_id: str
    private: bool
    branches: dict[str, str] = field(default_factory=dict)  # name -> commit oid
    tags: dict[str, str] = field(default_factory=dict)  # name -> commit oid
    # oid -> {"files": {path: bytes}, "lfs": {paths stored in LFS}, "parent", "summary"}
    commits: dict[str, dict] = field(default_factory=dict)
    lfs: dict[str, bytes] = field(default_factory=dict)  # sha256 -> content
    uploads: list[Upload] = field(default_factory=list)

    def resolve(self, revision: str) -> str | None:
        if revision in self.branches:
            return self.branches[revision]
        if revision in self.tags:
            return self.tags[revision]
        return revision if revision in self.commits else None

    def files(self, revision: str = "main") -> dict[str, bytes]:
        oid = self.resolve(revision)
        return dict(self.commits[oid]["files"]) if oid else {}

    def is_lfs(self, commit: str, path: str) -> bool:
        return path in self.commits[commit]["lfs"]

    def entry(self, commit: str, path: str) -> dict:
        """A file as the tree listing describes it: git oid (of the pointer for LFS files), size, LFS info."""
        data = self.commits[commit]["files"][path]
        if not self.is_lfs(commit, path):
            return {"type": "file", "oid": git_blob_oid(data), "size": len(data), "path": path}
        pointer = lfs_pointer(data)
        return {
            "type": "file",
            "oid": git_blob_oid(pointer),
            "size": len(data),
            "path": path,
            "lfs": {"oid": hashlib.sha256(data).hexdigest(), "size": len(data), "pointerSize": len(pointer)},
        }

    def folders(self, commit: str) -> dict[str, str]:
        """Every directory of a commit ("" = root) -> its git tree oid."""
        children: dict[str, dict[str, tuple[str, str]]] = {"": {}}
        for path in self.commits[commit]["files"]:
            parts = path.split("/")
            for i in range(1, len(parts)):
                children.setdefault("/".join(parts[:i]), {})
        oids: dict[str, str] = {}
        for folder in sorted(children, key=lambda f: -f.count("/") if f else 1):  # deepest first, root last
            entries = children[folder]
            prefix = folder + "/" if folder else ""
            for path in self.commits[commit]["files"]:
                if path.startswith(prefix) and "/" not in path[len(prefix) :]:
                    entries[path[len(prefix) :]] = ("100644", self.entry(commit, path)["oid"])
            for sub, oid in oids.items():
                if sub.startswith(prefix) and "/" not in sub[len(prefix) :]:
                    entries[sub[len(prefix) :]] = ("40000", oid)
            oids[folder] = git_tree_oid(entries)
        return oids


class HubError(Exception):
    def __init__(self, status: int, message: str, code: str | None = None, headers: dict | None = None):
        super().__init__(message)
        self.status, self.message, self.code, self.headers = status, message, code, headers or {}


class HubDouble:
    """`with HubDouble(token="hf_x") as hub:` serves on 127.0.0.1 at `hub.url` until the block ends."""

    # Entries per page of a tree listing (the hub pages recursive listings too); tests may lower it.
    tree_page_size = 1000

    def __init__(self, token: str = "hf_test_token", user: str = "test-user"):
        self.token, self.user = token, user
        self.repos: dict[tuple[str, str], Repo] = {}
        self.requests: list[tuple[str, str, int]] = []  # (method, path, status)
        self.unknown: list[tuple[str, str]] = []
        self.lock = threading.RLock()
        self._counter = 0
        self._server: ThreadingHTTPServer | None = None
        self._thread: threading.Thread | None = None

    # ---- lifecycle --------------------------------------------------------------------------------------
    def start(self) -> HubDouble:
        double = self

        class Handler(_Handler):
            hub = double

        self._server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self._server.daemon_threads = True
        self._thread = threading.Thread(target=self._server.serve_forever, name="hub-double", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        if self._server:
            self._server.shutdown()
            self._server.server_close()
            self._server = None

    def __enter__(self) -> HubDouble:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def url(self) -> str:
        host, port = self._server.server_address[:2]
        return f"http://{host}:{port}"

    # ---- queries for tests ------------------------------------------------------------------------------
    def repo(self, repo_id: str, repo_type: str = "dataset") -> Repo:
        return self.repos[(repo_type, repo_id)]

    # ---- request handling -------------------------------------------------------------------------------
    def handle(self, method: str, raw_path: str, headers, body: bytes) -> tuple[int, dict, bytes]:
        parts = urlsplit(raw_path)
        query = {k: v[-1] for k, v in parse_qs(parts.query).items()}
        path = parts.path
        for route_method, pattern, fn in self._routes():
            m = re.fullmatch(pattern, path)
            if m and route_method == method:
                args = [unquote(g) if g is not None else None for g in m.groups()]
                try:
                    with self.lock:
                        status, payload, *extra = fn(*args, query=query, headers=headers, body=body)
                except HubError as err:
                    extra = {**err.headers, "X-Error-Message": err.message}
                    if err.code:
                        extra["X-Error-Code"] = err.code
                    return err.status, extra, json.dumps({"error": err.message}).encode()
                out_headers = extra[0] if extra else {}
                if isinstance(payload, (bytes, bytearray)):
                    return status, out_headers, bytes(payload)
                return (
                    status,
                    {"Content-Type": "application/json", **out_headers},
                    json.dumps(payload).encode(),
                )
        with self.lock:
            self.unknown.append((method, raw_path))
        return 501, {}, json.dumps({"error": f"hub double: {method} {path} is not implemented"}).encode()

    def _routes(self):
        t = r"(models|datasets|spaces)"
        seg = r"([^/]+)"
        repo = rf"/api/{t}/{seg}/{seg}"
        return [
            ("POST", r"/api/repos/create", self.create_repo),
            ("POST", r"/api/validate-yaml", self.validate_yaml),
            ("GET", r"/api/whoami-v2", self.whoami),
            ("GET", r"/api/agent-harnesses", self.agent_harnesses),
            ("GET", rf"{repo}(?:/revision/{seg})?", self.repo_info),
            ("POST", rf"{repo}/preupload/{seg}", self.preupload),
            ("POST", rf"{repo}/commit/{seg}", self.commit),
            ("POST", rf"{repo}/branch/{seg}", self.create_branch),
            ("DELETE", rf"{repo}/branch/{seg}", self.delete_branch),
            ("POST", rf"{repo}/tag/{seg}", self.create_tag),
            ("DELETE", rf"{repo}/tag/{seg}", self.delete_tag),
            ("GET", rf"{repo}/refs", self.refs),
            ("GET", rf"{repo}/tree/{seg}(?:/(.+))?", self.tree),
            ("HEAD", rf"/(datasets/|spaces/)?{seg}/{seg}/resolve/{seg}/(.+)", self.resolve),
            ("GET", rf"/(datasets/|spaces/)?{seg}/{seg}/resolve/{seg}/(.+)", self.resolve),
            ("POST", rf"/(datasets/|spaces/)?{seg}/{seg}\.git/info/lfs/objects/batch", self.lfs_batch),
            ("PUT", rf"/_lfs/{t}/{seg}/{seg}/([0-9a-f]{{64}})", self.lfs_put),
            ("POST", rf"/_lfs-verify/{t}/{seg}/{seg}", self.lfs_verify),
        ]

    # ---- helpers ----------------------------------------------------------------------------------------
    def _authorized(self, headers) -> bool:
        return headers.get("Authorization", "") == f"Bearer {self.token}"

    def _require_auth(self, headers) -> None:
        if not self._authorized(headers):
            raise HubError(401, "Invalid credentials in Authorization header")

    def _get_repo(self, kind: str, ns: str, name: str, headers) -> Repo:
        repo = self.repos.get((kind.rstrip("s"), f"{ns}/{name}"))
        if repo is None or (repo.private and not self._authorized(headers)):
            raise HubError(404, "Repository not found", "RepoNotFound")
        return repo

    def _resolve(self, repo: Repo, revision: str) -> str:
        oid = repo.resolve(revision)
        if oid is None:
            raise HubError(404, f"Invalid rev id: {revision}", "RevisionNotFound")
        return oid

    def _new_commit(
        self, repo: Repo, parent: str | None, files: dict[str, bytes], lfs: set[str], summary: str
    ) -> str:
        self._counter += 1
        oid = hashlib.sha1(f"{repo.repo_id}:{self._counter}:{summary}:{time.time()}".encode()).hexdigest()
        repo.commits[oid] = {"files": files, "lfs": lfs, "parent": parent, "summary": summary}
        return oid

    def _repo_url(self, repo: Repo) -> str:
        return f"{self._base}/{TYPE_PREFIX[repo.repo_type]}{repo.repo_id}"

    @staticmethod
    def _json(body: bytes) -> dict:
        try:
            return json.loads(body or b"{}")
        except json.JSONDecodeError:
            raise HubError(400, "invalid JSON body") from None

    # ---- endpoints --------------------------------------------------------------------------------------
    def whoami(self, *, headers, **_):
        self._require_auth(headers)
        return 200, {"type": "user", "name": self.user, "orgs": [], "auth": {"type": "access_token"}}

    def agent_harnesses(self, **_):
        # huggingface_hub 1.x fetches this registry (once a day, cached in HF_HOME) to name the AI agent running
        # it in the user agent, unless HF_HUB_DISABLE_TELEMETRY is set. The double knows no harnesses.
        return 200, {"standardEnvVars": [], "harnesses": {}}

    def create_repo(self, *, headers, body, **_):
        self._require_auth(headers)
        req = self._json(body)
        repo_type = req.get("type") or "model"
        if repo_type not in TYPE_PREFIX or not req.get("name"):
            raise HubError(400, "invalid repo type or name")
        repo_id = f"{req.get('organization') or self.user}/{req['name']}"
        existing = self.repos.get((repo_type, repo_id))
        if existing:
            return 409, {
                "error": f"You already created this {repo_type} repo",
                "url": self._repo_url(existing),
            }
        # huggingface_hub >= 1.0 sends `visibility` ("private" | "public"; "protected" is for Spaces);
        # older clients sent a `private` boolean. Neither: public (a user namespace has no private default).
        visibility = req.get("visibility")
        if visibility not in (None, "private", "public", "protected") or (
            visibility == "protected" and repo_type != "space"
        ):
            raise HubError(400, f"invalid visibility {visibility!r}")
        private = visibility in ("private", "protected") if visibility else bool(req.get("private", False))
        repo = Repo(repo_type, repo_id, private=private)
        repo.branches["main"] = self._new_commit(
            repo, None, {".gitattributes": INITIAL_GITATTRIBUTES}, set(), "initial commit"
        )
        self.repos[(repo_type, repo_id)] = repo
        return 200, {"url": self._repo_url(repo), "name": repo_id, "id": repo_id}

    def validate_yaml(self, *, body, headers, **_):
        # HfApi._validate_yaml sends JSON; RepoCard.validate sends the same fields form-encoded.
        if "application/json" in headers.get("Content-Type", ""):
            content = self._json(body).get("content", "")
        else:
            content = parse_qs(body.decode(), keep_blank_values=True).get("content", [""])[-1]
        if not content.startswith("---\n") or "\n---" not in content[3:]:
            return 400, {"errors": [{"message": "README.md has no YAML metadata block"}], "warnings": []}
        return 200, {"errors": [], "warnings": []}

    def repo_info(self, kind, ns, name, revision, *, headers, query, **_):
        repo = self._get_repo(kind, ns, name, headers)
        oid = self._resolve(repo, revision or "main")
        siblings = []
        for path in sorted(repo.commits[oid]["files"]):
            sibling = {"rfilename": path}
            if query.get("blobs") in ("1", "true", "True"):  # files_metadata=True
                entry = repo.entry(oid, path)
                sibling.update(size=entry["size"], blobId=entry["oid"])
                if "lfs" in entry:
                    sibling["lfs"] = {
                        "sha256": entry["lfs"]["oid"],
                        "size": entry["lfs"]["size"],
                        "pointerSize": entry["lfs"]["pointerSize"],
                    }
            siblings.append(sibling)
        return 200, {
            "id": repo.repo_id,
            "author": repo.repo_id.split("/")[0],
            "sha": oid,
            "private": repo.private,
            "disabled": False,
            "gated": False,
            "xetEnabled": False,
            "tags": [],
            "siblings": siblings,
        }

    def preupload(self, kind, ns, name, revision, *, headers, body, **_):
        self._require_auth(headers)
        repo = self._get_repo(kind, ns, name, headers)
        head = self._resolve(repo, revision)
        existing = repo.commits[head]["files"]
        out = []
        for f in self._json(body).get("files", []):
            sample = base64.b64decode(f.get("sample", ""))
            lfs = f["path"].lower().endswith(LFS_SUFFIXES) or f["size"] > REGULAR_MAX_BYTES or b"\0" in sample
            old = existing.get(f["path"])
            # The oid of the file already there: sha256 if it is in LFS, its git blob oid otherwise.
            oid = (
                None
                if old is None
                else (hashlib.sha256(old).hexdigest() if repo.is_lfs(head, f["path"]) else git_blob_oid(old))
            )
            out.append(
                {
                    "path": f["path"],
                    "uploadMode": "lfs" if lfs else "regular",
                    "shouldIgnore": False,
                    "oid": oid,
                }
            )
        return 200, {"files": out, "commitOid": repo.branches.get(revision)}

    def commit(self, kind, ns, name, revision, *, headers, body, query, **_):
        self._require_auth(headers)
        repo = self._get_repo(kind, ns, name, headers)
        if query.get("create_pr"):
            raise HubError(501, "hub double: pull requests are not implemented")
        if revision not in repo.branches:
            raise HubError(404, f"Invalid rev id: {revision}", "RevisionNotFound")
        parent = repo.branches[revision]
        files = dict(repo.commits[parent]["files"])
        lfs_paths = set(repo.commits[parent]["lfs"])
        lines = [json.loads(line) for line in body.decode().splitlines() if line.strip()]
        if not lines or lines[0].get("key") != "header":
            raise HubError(400, "commit payload must start with a header line")
        header = lines[0]["value"]
        if header.get("parentCommit") and header["parentCommit"] != parent:
            raise HubError(412, "A commit has happened since. Please refresh and try again.")
        arrived = []
        for line in lines[1:]:
            key, value = line.get("key"), line.get("value", {})
            if key == "file":
                data = base64.b64decode(value["content"])
                files[value["path"]] = data
                lfs_paths.discard(value["path"])
                arrived.append((value["path"], data, False))
            elif key == "lfsFile":
                data = repo.lfs.get(value["oid"])
                if data is None or len(data) != value["size"]:
                    raise HubError(400, f"LFS object {value['oid']} for {value['path']} was never uploaded")
                files[value["path"]] = data
                lfs_paths.add(value["path"])
                arrived.append((value["path"], data, True))
            elif key == "deletedFile":
                if value["path"] not in files:
                    raise HubError(404, "A file with this name doesn't exist", "EntryNotFound")
                del files[value["path"]]
                lfs_paths.discard(value["path"])
            elif key == "deletedFolder":
                prefix = value["path"].rstrip("/") + "/"
                for p in [p for p in files if p.startswith(prefix)]:
                    del files[p]
                    lfs_paths.discard(p)
            else:
                self.unknown.append(("commit-op", json.dumps(line)[:200]))
                raise HubError(400, f"hub double: unknown commit operation {key!r}")
        oid = self._new_commit(repo, parent, files, lfs_paths, header.get("summary", ""))
        repo.branches[revision] = oid
        repo.uploads += [Upload(p, d, lfs, revision, oid) for p, d, lfs in arrived]
        return 200, {
            "success": True,
            "commitOid": oid,
            "commitUrl": f"{self._repo_url(repo)}/commit/{oid}",
            "pullRequestUrl": None,
        }

    def create_branch(self, kind, ns, name, branch, *, headers, body, **_):
        self._require_auth(headers)
        repo = self._get_repo(kind, ns, name, headers)
        if branch in repo.branches:
            raise HubError(409, f"Reference already exists: refs/heads/{branch}")
        start = self._json(body).get("startingPoint")
        repo.branches[branch] = self._resolve(repo, start) if start else repo.branches["main"]
        return 200, {}

    def delete_branch(self, kind, ns, name, branch, *, headers, **_):
        self._require_auth(headers)
        repo = self._get_repo(kind, ns, name, headers)
        if branch not in repo.branches or branch == "main":
            raise HubError(404, f"Invalid rev id: {branch}", "RevisionNotFound")
        del repo.branches[branch]
        return 200, {}

    def create_tag(self, kind, ns, name, revision, *, headers, body, **_):
        self._require_auth(headers)
        repo = self._get_repo(kind, ns, name, headers)
        tag = self._json(body).get("tag")
        if not tag:
            raise HubError(400, "missing tag name")
        if tag in repo.tags:
            raise HubError(409, f"Tag {tag} already exists")
        repo.tags[tag] = self._resolve(repo, revision)
        return 200, {}

    def delete_tag(self, kind, ns, name, tag, *, headers, **_):
        self._require_auth(headers)
        repo = self._get_repo(kind, ns, name, headers)
        if tag not in repo.tags:
            raise HubError(404, f"Invalid rev id: {tag}", "RevisionNotFound")
        del repo.tags[tag]
        return 200, {}

    def refs(self, kind, ns, name, *, headers, **_):
        repo = self._get_repo(kind, ns, name, headers)
        return 200, {
            "branches": [
                {"name": b, "ref": f"refs/heads/{b}", "targetCommit": c} for b, c in repo.branches.items()
            ],
            "tags": [{"name": t, "ref": f"refs/tags/{t}", "targetCommit": c} for t, c in repo.tags.items()],
            "converts": [],
            "pullRequests": [],
        }

    def tree(self, kind, ns, name, revision, path, *, headers, query, **_):
        """`list_repo_tree`: the entries under `path` (all of them with recursive=true), folders included,
        sorted by path, `tree_page_size` per page with a `Link: <next>; rel="next"` header while more remain."""
        repo = self._get_repo(kind, ns, name, headers)
        oid = self._resolve(repo, revision)
        files = repo.commits[oid]["files"]
        folders = repo.folders(oid)
        base = (path or "").strip("/")
        if base and base not in folders:
            raise HubError(404, f'{base} does not exist on "{revision}"', "EntryNotFound")
        prefix = base + "/" if base else ""
        recursive = query.get("recursive", "false").lower() in ("1", "true")
        entries = []
        for folder, tree_oid in folders.items():
            if folder and folder.startswith(prefix) and (recursive or "/" not in folder[len(prefix) :]):
                entries.append({"type": "directory", "oid": tree_oid, "size": 0, "path": folder})
        for p in files:
            if p.startswith(prefix) and (recursive or "/" not in p[len(prefix) :]):
                entries.append(repo.entry(oid, p))
        entries.sort(key=lambda e: e["path"])
        if query.get("expand", "false").lower() in ("1", "true"):
            commit = {"id": oid, "title": repo.commits[oid]["summary"], "date": "2025-01-01T00:00:00.000Z"}
            entries = [{**e, "lastCommit": commit} for e in entries]
        start = int(query.get("cursor") or 0)
        page = entries[start : start + self.tree_page_size]
        extra = {}
        if start + self.tree_page_size < len(entries):
            where = f"{kind}/{repo.repo_id}/tree/{quote(revision, safe='')}"
            if base:
                where += f"/{quote(base, safe='')}"
            params = urlencode({**query, "cursor": start + self.tree_page_size})
            extra["Link"] = f'<{self._base}/api/{where}?{params}>; rel="next"'
        return 200, page, extra

    def resolve(self, prefix, ns, name, revision, path, *, headers, **_):
        """`HEAD`/`GET .../resolve/{rev}/{path}`: the file with the headers `hf_hub_download` reads."""
        kind = {"datasets/": "datasets", "spaces/": "spaces"}.get(prefix or "", "models")
        repo = self._get_repo(kind, ns, name, headers)
        oid = self._resolve(repo, revision)
        data = repo.commits[oid]["files"].get(path)
        if data is None:
            raise HubError(404, "Entry not found", "EntryNotFound", headers={"X-Repo-Commit": oid})
        entry = repo.entry(oid, path)
        out = {
            "X-Repo-Commit": oid,
            "ETag": f'"{entry["oid"]}"',
            "Accept-Ranges": "bytes",
            "Content-Type": "application/octet-stream",
        }
        if "lfs" in entry:
            out["X-Linked-Etag"] = f'"{entry["lfs"]["oid"]}"'
            out["X-Linked-Size"] = str(entry["lfs"]["size"])
        ranged = re.fullmatch(r"bytes=(\d+)-(\d*)", headers.get("Range", "") or "")
        if ranged:
            start = int(ranged.group(1))
            end = min(int(ranged.group(2)) if ranged.group(2) else len(data) - 1, len(data) - 1)
            if start >= len(data):
                raise HubError(
                    416, "Requested Range Not Satisfiable", headers={"Content-Range": f"bytes */{len(data)}"}
                )
            out["Content-Range"] = f"bytes {start}-{end}/{len(data)}"
            return 206, data[start : end + 1], out
        return 200, data, out

    def lfs_batch(self, prefix, ns, name, *, headers, body, **_):
        self._require_auth(headers)
        kind = {"datasets/": "datasets", "spaces/": "spaces"}.get(prefix or "", "models")
        repo = self._get_repo(kind, ns, name, headers)
        req = self._json(body)
        if req.get("operation") != "upload" or "basic" not in req.get("transfers", ["basic"]):
            raise HubError(400, "hub double: only basic LFS uploads are implemented")
        objects = []
        for obj in req.get("objects", []):
            entry = {"oid": obj["oid"], "size": obj["size"], "authenticated": True}
            if obj["oid"] not in repo.lfs:
                where = f"{kind}/{repo.repo_id}"
                entry["actions"] = {
                    "upload": {"href": f"{self._base}/_lfs/{where}/{obj['oid']}"},
                    "verify": {"href": f"{self._base}/_lfs-verify/{where}"},
                }
            objects.append(entry)
        return 200, {"transfer": "basic", "objects": objects}

    def lfs_put(self, kind, ns, name, oid, *, body, **_):
        # Like S3's pre-signed URLs: no Authorization header, the URL is the credential.
        repo = self._get_repo(kind, ns, name, {"Authorization": f"Bearer {self.token}"})
        if hashlib.sha256(body).hexdigest() != oid:
            raise HubError(400, "uploaded content does not match its sha256")
        repo.lfs[oid] = body
        return 200, b""

    def lfs_verify(self, kind, ns, name, *, headers, body, **_):
        self._require_auth(headers)
        repo = self._get_repo(kind, ns, name, headers)
        req = self._json(body)
        data = repo.lfs.get(req.get("oid"))
        if data is None or len(data) != req.get("size"):
            raise HubError(404, "LFS object not found")
        return 200, {}

    @property
    def _base(self) -> str:
        return self.url


class _Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    hub: HubDouble

    def _body(self) -> bytes:
        if "chunked" in self.headers.get("Transfer-Encoding", "").lower():
            chunks = []
            while True:
                size = int(self.rfile.readline().split(b";")[0].strip() or b"0", 16)
                if size == 0:
                    while self.rfile.readline() not in (b"\r\n", b"\n", b""):
                        pass  # trailers
                    break
                chunks.append(self.rfile.read(size))
                self.rfile.readline()
            return b"".join(chunks)
        return self.rfile.read(int(self.headers.get("Content-Length") or 0))

    def _dispatch(self) -> None:
        body = self._body()
        status, headers, payload = self.hub.handle(self.command, self.path, self.headers, body)
        with self.hub.lock:
            self.hub.requests.append((self.command, self.path, status))
        self.send_response(status)
        for k, v in headers.items():
            self.send_header(k, v)
        self.send_header("Content-Length", str(len(payload)))
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(payload)

    do_GET = do_POST = do_PUT = do_DELETE = do_HEAD = _dispatch  # noqa: N815  (the stdlib's names)

    def log_message(self, format, *args) -> None:  # noqa: A002  (the stdlib's signature)
        pass
