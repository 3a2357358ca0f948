#!/usr/bin/env bash
# The compose cluster, for real: builds the image offline, starts a coordinator and 3 workers,
# renders the cornell box through the REST API and checks the EXR is bitwise the one
# `coordinator render` makes; then kills a worker and scales to 5 mid-job, restarts the
# coordinator mid-job, and checks tokens. Tears everything down (containers, network, volume)
# whatever happens. Needs docker, docker-compose (v1) or docker compose (v2), curl, and the
# release binaries (built if missing).
set -euo pipefail
cd "$(dirname "$0")/.."
start=$(date +%s)
project="renderfarm-ci-$$"
tmp=$(mktemp -d)
if docker compose version >/dev/null 2>&1; then compose_cmd=(docker compose); else compose_cmd=(docker-compose); fi
export FARM_TOKEN="join-$RANDOM$RANDOM" FARM_API_TOKEN="api-$RANDOM$RANDOM" FARM_IMAGE=renderfarm:local
export FARM_LEASE_TIMEOUT=3 FARM_LOG=warn
export FARM_PORT=${FARM_PORT:-$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')}
url="http://127.0.0.1:$FARM_PORT"
compose() { "${compose_cmd[@]}" -p "$project" -f deploy/docker-compose.yml "$@"; }
cleanup() {
    status=$?
    if [ $status -ne 0 ]; then
        echo "== cluster test failed; coordinator log:" >&2
        compose logs --no-color --tail 40 coordinator >&2 || true
    fi
    compose down -v --remove-orphans --timeout 5 >/dev/null 2>&1 || true
    rm -rf "$tmp"
    exit $status
}
trap cleanup EXIT

bin=target/release
auth=(-H "Authorization: Bearer $FARM_API_TOKEN")
step() { echo "== $* ($(( $(date +%s) - start )) s)"; }
same() { "$bin/examples/exr_same" "$@"; }

job_state() { curl -sf "${auth[@]}" "$url/api/v1/jobs/$1" | python3 -c 'import json,sys; s=json.load(sys.stdin); print(s["state"], s["samples_done"], s["samples_planned"])'; }
wait_for() { # job, python condition on (state, done, planned), timeout seconds
    local end=$(( $(date +%s) + $3 )) line
    while [ "$(date +%s)" -lt $end ]; do
        if line=$(job_state "$1" 2>/dev/null); then
            if python3 -c "state, done, planned = '$line'.split()[0], *map(int, '$line'.split()[1:]); import sys; sys.exit(0 if ($2) else 1)"; then
                echo "   job $1: $line"; return 0
            fi
            case "$line" in failed*|cancelled*) echo "job $1 ended: $line" >&2; return 1;; esac
        fi
        sleep 0.2
    done
    echo "timed out waiting for job $1 ($2); last: ${line:-none}" >&2
    return 1
}
submit_job() { # settings json -> job id
    curl -sf "${auth[@]}" -H 'content-type: application/json' "$url/api/v1/jobs" \
        -d "{\"scene\": \"$scene\", \"settings\": $1}" | python3 -c 'import json,sys; print(json.load(sys.stdin)["id"])'
}
fetch() { curl -sf "${auth[@]}" -o "$2" "$url/api/v1/jobs/$1/frames/0.exr"; }

step "building the image offline"
deploy/build-image.sh
[ -x "$bin/examples/exr_same" ] || cargo build --release -p coordinator --example exr_same

step "starting the cluster: coordinator + 3 workers"
compose up -d --scale worker=3
for _ in $(seq 100); do curl -sf "$url/healthz" >/dev/null && break; sleep 0.2; done
curl -sf "$url/healthz" >/dev/null

settings='{"width": 128, "height": 128, "spp": 512, "samples_per_task": 32, "tile_size": 32, "max_depth": 16}'
echo "$settings" > "$tmp/settings.json"
step "reference: coordinator render on the host"
"$bin/coordinator" render scenes/cornell-box.gltf -o "$tmp/reference.exr" --settings "$tmp/settings.json" --workers 2

step "a job through the REST API (coordinator submit)"
"$bin/coordinator" submit scenes/cornell-box.gltf -o "$tmp/submitted.exr" --settings "$tmp/settings.json" \
    --url "$url" --api-token "$FARM_API_TOKEN"
same "$tmp/reference.exr" "$tmp/submitted.exr" --samples 512

scene=$(curl -sf "${auth[@]}" "$url/api/v1/jobs" | python3 -c 'import json,sys; print(json.load(sys.stdin)["jobs"][0]["scene"])')
step "kill a worker and scale to 5 mid-job"
id=$(submit_job "$settings")
wait_for "$id" "done > 0" 60
# Whole output first: `| head -1` would close the pipe early and, under pipefail, fail on
# compose's SIGPIPE (exit 141) whenever compose writes its second line late.
workers=$(compose ps -q worker)
victim=${workers%%$'\n'*}
docker kill "$victim" >/dev/null
compose up -d --scale worker=5 --no-recreate
wait_for "$id" "state == 'done'" 180
[ "$(compose ps -q worker | wc -l)" -ge 5 ]
fetch "$id" "$tmp/killed.exr"
same "$tmp/reference.exr" "$tmp/killed.exr" --samples 512

step "restart the coordinator mid-job"
id=$(submit_job "$settings")
wait_for "$id" "done > planned // 5" 60
compose restart coordinator
wait_for "$id" "state == 'done'" 180
fetch "$id" "$tmp/restarted.exr"
same "$tmp/reference.exr" "$tmp/restarted.exr" --samples 512

step "tokens"
network="${project}_default"
if out=$(docker run --rm --network "$network" -e RENDERFARM_TOKEN=wrong "$FARM_IMAGE" worker --join http://coordinator:8080 2>&1); then
    echo "a worker with a wrong token was let in" >&2; exit 1
fi
grep -q "join token refused" <<<"$out" || { echo "unclear refusal: $out" >&2; exit 1; }
if out=$(docker run --rm --network "$network" "$FARM_IMAGE" worker --join http://coordinator:8080 2>&1); then
    echo "a worker without a token was let in" >&2; exit 1
fi
grep -q "needs a join token" <<<"$out" || { echo "unclear refusal: $out" >&2; exit 1; }
code=$(curl -s -o /dev/null -w '%{http_code}' -H 'Authorization: Bearer wrong' "$url/api/v1/jobs")
[ "$code" = 401 ] || { echo "wrong API token answered $code" >&2; exit 1; }
code=$(curl -s -o /dev/null -w '%{http_code}' "$url/api/v1/jobs")
[ "$code" = 401 ] || { echo "missing API token answered $code" >&2; exit 1; }

step "cluster test passed"
