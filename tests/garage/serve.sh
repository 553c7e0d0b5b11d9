#!/usr/bin/env bash
# A single-node Garage (an S3-compatible distributed object store) on
# loopback, for `voxserve bench store` and `bench out-of-core` against a real
# distributed store (the tests use s3s-fs, which builds in seconds). Garage
# takes half an hour to build on two cores: build it once, outside the
# repository:
#
#   cargo install garage --version 2.5.0 --locked --root ~/.cache/voxserve/garage
#
# Usage: bash tests/garage/serve.sh GARAGE FOLDER [PORT]
#
# Starts GARAGE (the binary) with its data, metadata and configuration in
# FOLDER (kept: run it again on the same folder and the stores are still
# there), the S3 API on 127.0.0.1:PORT (3900; RPC on PORT+1, admin on
# PORT+3), with bucket `scans` and a key allowed to read and write it, and
# prints the environment voxserve needs as export lines. Garage runs in the
# background until killed: its pid is in FOLDER/garage.pid, its log in
# FOLDER/garage.log.
set -euo pipefail
if [[ $# -lt 2 ]]; then
  echo "usage: bash tests/garage/serve.sh GARAGE FOLDER [PORT]" >&2
  exit 2
fi
garage=$1
mkdir -p "$2"
dir=$(cd "$2" && pwd)
port=${3:-3900}
config=$dir/garage.toml
hex() { head -c "$1" /dev/urandom | od -An -tx1 | tr -d ' \n'; }
if [[ ! -f $config ]]; then
  mkdir -p "$dir/meta" "$dir/data"
  cat >"$config" <<CONFIG
metadata_dir = "$dir/meta"
data_dir = "$dir/data"
db_engine = "sqlite"
replication_factor = 1
rpc_bind_addr = "127.0.0.1:$((port + 1))"
rpc_public_addr = "127.0.0.1:$((port + 1))"
rpc_secret = "$(hex 32)"

[s3_api]
s3_region = "garage"
api_bind_addr = "127.0.0.1:$port"
root_domain = ".s3.garage.localhost"

[admin]
api_bind_addr = "127.0.0.1:$((port + 3))"
CONFIG
  chmod 600 "$config"
  # An access key as Garage writes them: GK and 24 hex digits, a 64-digit secret.
  echo "GK$(hex 12) $(hex 32)" >"$dir/key"
  chmod 600 "$dir/key"
fi
read -r key_id secret <"$dir/key"
g() { "$garage" -c "$config" "$@"; }
g server >"$dir/garage.log" 2>&1 &
echo $! >"$dir/garage.pid"
for _ in $(seq 100); do
  g status >/dev/null 2>&1 && break
  sleep 0.2
done
g status >/dev/null || { cat "$dir/garage.log" >&2; exit 1; }
node=$(g node id -q 2>/dev/null | cut -d@ -f1)
layout=$(g layout show 2>/dev/null)
if [[ $layout == *"No nodes currently have a role"* ]]; then
  g layout assign -z local -c 100G "$node" >/dev/null
  g layout apply --version 1 >/dev/null
fi
g bucket info scans >/dev/null 2>&1 || g bucket create scans >/dev/null
g key info "$key_id" >/dev/null 2>&1 || g key import --yes -n voxserve "$key_id" "$secret" >/dev/null
g bucket allow --read --write --owner scans --key "$key_id" >/dev/null
cat <<ENV
export AWS_ACCESS_KEY_ID=$key_id
export AWS_SECRET_ACCESS_KEY=$secret
export AWS_REGION=garage
export AWS_ENDPOINT_URL=http://127.0.0.1:$port
ENV
