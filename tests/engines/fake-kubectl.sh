#!/usr/bin/env bash
# A stand-in for kubectl with the two Jobs of deploy/k8s as its whole cluster, for testing deploy/k8s/run.sh where
# no cluster runs: the state is files in $FAKE_K8S (NAME.exists, NAME.suspend = true|false, NAME.conditions = the
# true condition types, space-separated), which the test changes as a cluster would; every call is appended to
# $FAKE_K8S/calls. It answers the calls run.sh makes (and its earlier version's) as kubectl does:
#   kustomize DIR                      -> $FAKE_K8S/rendered.yaml
#   apply -f FILE [-l SELECTOR] | apply -k DIR
#                                      -> each Job applied: exists, and its spec.suspend from the manifest
#   -n NS get job/NAME --ignore-not-found -o name|jsonpath=...
#   -n NS patch job/NAME ... '{"spec":{"suspend":false}}'
#   -n NS wait --for=condition=complete job/NAME --timeout=-1s   (blocks until Complete, even when Failed, as kubectl)
set -euo pipefail
s=${FAKE_K8S:?}
echo "$*" >>"$s/calls"
[ "${1:-}" != -n ] || shift 2
verb=$1
shift
job_of() { local a; for a in "$@"; do case "$a" in job/*) echo "${a#job/}" ;; esac; done; }
case "$verb" in
kustomize) cat "$s/rendered.yaml" ;;
apply)
    file="" selector=""
    while [ $# -gt 0 ]; do
        case "$1" in
        -f) file=$2; shift 2 ;;
        -k) file=$s/rendered.yaml; shift 2 ;;
        -l) selector=$2; shift 2 ;;
        *) shift ;;
        esac
    done
    for job in dynforge-generate dynforge-merge; do
        component=${job#dynforge-}
        grep -q "name: $job\$" "$file" || continue
        [ "$selector" != "app.kubernetes.io/component!=$component" ] || continue
        touch "$s/$job.exists"
        # The manifest's spec.suspend (the first "suspend:" after the Job's name), false when absent.
        suspend=$(awk -v job="$job" '$0 ~ "name: " job "$" { on = 1 } on && /^ *suspend:/ { print $2; exit }
            on && /^---/ { exit }' "$file")
        echo "${suspend:-false}" >"$s/$job.suspend"
        echo "job.batch/$job configured"
    done
    ;;
get)
    job=$(job_of "$@")
    [ -e "$s/$job.exists" ] || exit 0
    case "$*" in
    *"-o name"*) echo "job.batch/$job" ;;
    *conditions*) if [ -e "$s/$job.conditions" ]; then tr -s ' \n' '  ' <"$s/$job.conditions"; fi ;;
    *spec.suspend*) cat "$s/$job.suspend" ;;
    *) echo "fake-kubectl: unexpected get $*" >&2; exit 1 ;;
    esac
    ;;
patch)
    job=$(job_of "$@")
    [ -e "$s/$job.exists" ] || { echo "Error from server (NotFound): jobs.batch \"$job\" not found" >&2; exit 1; }
    case "$*" in *'"suspend":false'*) echo false >"$s/$job.suspend" ;; esac
    echo "job.batch/$job patched"
    ;;
wait)
    job=$(job_of "$@")
    until grep -qw Complete "$s/$job.conditions" 2>/dev/null; do sleep 0.1; done
    echo "job.batch/$job condition met"
    ;;
*) echo "fake-kubectl: unexpected call: $verb $*" >&2; exit 1 ;;
esac
