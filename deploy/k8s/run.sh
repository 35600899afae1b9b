#!/usr/bin/env bash
# Applies the kustomization (namespace, volume, the generation's Indexed Job, the suspended merge Job), waits for the
# generation to complete, then releases the merge. Usage: deploy/k8s/run.sh [KUSTOMIZATION_DIR]
set -euo pipefail
dir=${1:-$(cd "$(dirname "$0")" && pwd)}
kubectl apply -k "$dir"
kubectl -n dynforge wait --for=condition=complete job/dynforge-generate --timeout=-1s
kubectl -n dynforge patch job/dynforge-merge --type=merge -p '{"spec":{"suspend":false}}'
kubectl -n dynforge wait --for=condition=complete job/dynforge-merge --timeout=-1s
