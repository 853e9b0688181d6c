#!/usr/bin/env bash
# Makes a test certificate authority, the router's TLS certificate, client certificates for
# mutual TLS, one password per role and the router's user/password dictionary.
#
#   deploy/make-test-ca.sh OUT_DIR [--router-ip IP]... [--router-dns NAME]... [--days N] [--force]
#
# e.g. deploy/make-test-ca.sh /tmp/fsrl-secrets --router-ip 10.0.0.1 --router-dns router.lan
#
# OUT_DIR receives (keys and passwords mode 0600):
#   certs/ca.crt  certs/ca.key                 the CA (keep ca.key off the cluster)
#   certs/router.crt certs/router.key          the router's certificate: CN=router, SANs =
#                                              127.0.0.1, localhost and every --router-ip/-dns
#   certs/{learner,actor,evaluator,monitor}.{crt,key}
#                                              client certificates, CN = role (optional mTLS)
#   {learner,actor,evaluator,monitor}.password one random password per role (first line)
#   router-users.txt                           the router's dictionary: `user:password` lines
#
# It is a *test* CA (openssl, EC P-256, no revocation); use your organisation's PKI in
# production. Needs openssl >= 1.1.1.
set -euo pipefail

usage() { sed -n '2,9p' "$0" >&2; exit 2; }

out=""
days=365
force=0
sans=("IP:127.0.0.1" "DNS:localhost")
while [ $# -gt 0 ]; do
  case "$1" in
    --router-ip) [ $# -ge 2 ] || usage; sans+=("IP:$2"); shift 2 ;;
    --router-dns) [ $# -ge 2 ] || usage; sans+=("DNS:$2"); shift 2 ;;
    --days) [ $# -ge 2 ] || usage; days="$2"; shift 2 ;;
    --force) force=1; shift ;;
    -h|--help) usage ;;
    -*) echo "unknown option $1" >&2; usage ;;
    *) [ -z "$out" ] || usage; out="$1"; shift ;;
  esac
done
[ -n "$out" ] || usage
command -v openssl >/dev/null || { echo "error: openssl is not installed" >&2; exit 1; }
if [ -e "$out/certs/ca.key" ] && [ "$force" -ne 1 ]; then
  echo "error: $out/certs/ca.key exists; pass --force to replace every file" >&2
  exit 1
fi

umask 077
mkdir -p "$out/certs"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT

key() { openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$1" 2>/dev/null; }

# The CA.
key "$out/certs/ca.key"
openssl req -x509 -new -key "$out/certs/ca.key" -sha256 -days "$days" \
  -subj "/CN=fsrl test CA" -out "$out/certs/ca.crt" \
  -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign"

# sign NAME CN EXTFILE: a leaf certificate signed by the CA.
sign() {
  key "$out/certs/$1.key"
  openssl req -new -key "$out/certs/$1.key" -subj "/CN=$2" -out "$tmp/$1.csr"
  openssl x509 -req -in "$tmp/$1.csr" -CA "$out/certs/ca.crt" -CAkey "$out/certs/ca.key" \
    -CAcreateserial -CAserial "$tmp/ca.srl" -days "$days" -sha256 \
    -extfile "$3" -out "$out/certs/$1.crt" 2>/dev/null
}

san_list="$(IFS=,; echo "${sans[*]}")"
cat >"$tmp/router.ext" <<EOF
basicConstraints=CA:FALSE
keyUsage=critical,digitalSignature,keyEncipherment
extendedKeyUsage=serverAuth,clientAuth
subjectAltName=$san_list
EOF
sign router router "$tmp/router.ext"

cat >"$tmp/client.ext" <<EOF
basicConstraints=CA:FALSE
keyUsage=critical,digitalSignature,keyEncipherment
extendedKeyUsage=clientAuth
EOF
: >"$tmp/router-users.txt"
for role in learner actor evaluator monitor; do
  sign "$role" "$role" "$tmp/client.ext"
  pw="$(openssl rand -hex 24)"
  printf '%s\n' "$pw" >"$out/$role.password"
  printf '%s:%s\n' "$role" "$pw" >>"$tmp/router-users.txt"
done
mv "$tmp/router-users.txt" "$out/router-users.txt"
chmod 0755 "$out/certs"
chmod 0644 "$out"/certs/*.crt
chmod 0600 "$out"/certs/*.key "$out"/*.password "$out/router-users.txt"

openssl verify -CAfile "$out/certs/ca.crt" "$out/certs/router.crt" >/dev/null
echo "test CA, certificates and passwords written to $out (router SANs: $san_list)"
