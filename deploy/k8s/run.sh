#!/usr/bin/env bash
# Applies the kustomization (namespace, volume, the generation's Indexed Job, the suspended merge Job), waits for the
# generation to complete, releases the merge and waits for it. Exits 0 when the merge Job completed, non-zero as soon
# as a Job has failed (naming it and how to look at it).
#   deploy/k8s/run.sh [KUSTOMIZATION_DIR]          (default: deploy/k8s; DYNFORGE_NAMESPACE: dynforge)
# Safe to run again at any time: a merge Job already released (running or finished) is neither applied again nor
# suspended; to retry a failed Job, delete it (`kubectl -n dynforge delete job/NAME`) and run this again (the
# volume keeps the partitions and the merge; both Jobs pick up where they stopped). deploy/README.md is the guide.
set -euo pipefail
dir=${1:-$(cd "$(dirname "$0")" && pwd)}
ns=${DYNFORGE_NAMESPACE:-dynforge}
poll=${DYNFORGE_POLL_SECONDS:-10}
say() { echo "run.sh: $*" >&2; }

rendered=$(mktemp)
trap 'rm -f "$rendered"' EXIT
kubectl kustomize "$dir" >"$rendered"
if grep -q 'storageClassName: *replace-with-a-readwritemany-class' "$rendered"; then
    say "the PersistentVolumeClaim's storageClassName is still the placeholder: set a ReadWriteMany class of your"
    say "cluster (kubectl get storageclass) in deploy/k8s/volume.yaml or an overlay (deploy/README.md)"
    exit 2
fi

# The Job's state: Complete, Failed, Suspended, Running or Absent.
state() {
    local conditions suspend
    conditions=$(kubectl -n "$ns" get "job/$1" --ignore-not-found \
        -o jsonpath='{range .status.conditions[?(@.status=="True")]}{.type}{" "}{end}')
    if [ -z "$(kubectl -n "$ns" get "job/$1" --ignore-not-found -o name)" ]; then
        echo Absent
        return
    fi
    case " $conditions " in
    *" Complete "*) echo Complete ;;
    *" Failed "*) echo Failed ;;
    *)
        suspend=$(kubectl -n "$ns" get "job/$1" -o jsonpath='{.spec.suspend}')
        if [ "$suspend" = true ]; then echo Suspended; else echo Running; fi
        ;;
    esac
}

# Waits until job $1 completes (returns) or fails (exits 1).
wait_for() {
    local s last=""
    while :; do
        s=$(state "$1")
        case "$s" in
        Complete)
            say "job/$1 completed"
            return 0
            ;;
        Failed)
            say "job/$1 failed: kubectl -n $ns describe job/$1; kubectl -n $ns logs job/$1"
            say "to retry: kubectl -n $ns delete job/$1, then run $0 again"
            exit 1
            ;;
        Absent)
            say "job/$1 does not exist (deleted meanwhile?)"
            exit 1
            ;;
        esac
        if [ "$s" != "$last" ]; then say "job/$1: $s"; fi
        last=$s
        sleep "$poll"
    done
}

# A merge Job already released (running or finished) must not be applied again: its `suspend: true` would suspend
# it and delete its running pod.
merge=$(state dynforge-merge)
if [ "$merge" = Absent ] || [ "$merge" = Suspended ]; then
    kubectl apply -f "$rendered"
else
    say "job/dynforge-merge is already released ($merge): applying everything else"
    kubectl apply -f "$rendered" -l 'app.kubernetes.io/component!=merge'
fi
wait_for dynforge-generate
if [ "$(state dynforge-merge)" = Suspended ]; then
    kubectl -n "$ns" patch job/dynforge-merge --type=merge -p '{"spec":{"suspend":false}}'
fi
wait_for dynforge-merge
