#!/usr/bin/env bash
# Validates the manifests in this folder against the Kubernetes API schema, offline: the PyPI
# package kubernetes-validate bundles the schemas. Strict: an unknown field is an error, so a
# misspelt key fails here instead of being dropped by the API server.
#
#   KUBERNETES_VALIDATE    the kubernetes-validate executable (default: found on PATH)
#   KUBERNETES_VERSIONS    API versions to check against (default: "1.29.0 1.37.0")
#
# No cluster runs these manifests in the tests; see docs/BATCH.md.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
validate="${KUBERNETES_VALIDATE:-kubernetes-validate}"
command -v "$validate" >/dev/null ||
  { echo "validate.sh: $validate not found (pip install kubernetes-validate)" >&2; exit 1; }
manifests=("$here"/*.yaml)
for version in ${KUBERNETES_VERSIONS:-1.29.0 1.37.0}; do
  "$validate" --strict --kubernetes-version "$version" "${manifests[@]}"
done
echo "valid against the Kubernetes API schema (${KUBERNETES_VERSIONS:-1.29.0 1.37.0}): ${manifests[*]##*/}"
