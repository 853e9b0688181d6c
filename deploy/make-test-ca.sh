#!/usr/bin/env bash
# Makes a test certificate authority, the router's TLS certificate, client certificates for
# mutual TLS, one password per user and the router's user/password dictionary.
#
#   deploy/make-test-ca.sh OUT_DIR [--router-ip IP]... [--router-dns NAME]... [--actors N]
#                                  [--days N] [--force]
#
# e.g. deploy/make-test-ca.sh /tmp/fsrl-secrets --router-ip 10.0.0.1 --router-dns router.lan
#
# The users: learner, evaluator, monitor and one per actor, actor-0 .. actor-<N-1> (--actors N,
# default 4: the actors deploy/router.json5 lists).
#
# OUT_DIR receives (keys and passwords mode 0600):
#   certs/ca.crt  certs/ca.key                 the CA (keep ca.key off the cluster)
#   certs/router.crt certs/router.key          the router's certificate: CN=router, SANs =
#                                              127.0.0.1, localhost and every --router-ip/-dns
#   certs/<user>.{crt,key}                     client certificates, CN = user (optional mTLS)
#   <user>.password                            one random password per user (first line):
#                                              learner, evaluator, monitor, actor-<id>
#   router-users.txt                           the router's dictionary: `user:password` lines
#
# It is a *test* CA (openssl, EC P-256, no revocation); use your organisation's PKI in
# production. Needs openssl >= 1.1.1.
set -euo pipefail

usage() { sed -n '2,13p' "$0" >&2; exit 2; }

out=""
days=365
actors=4
force=0
sans=("IP:127.0.0.1" "DNS:localhost")
while [ $# -gt 0 ]; do
  case "$1" in
    --router-ip) [ $# -ge 2 ] || usage; sans+=("IP:$2"); shift 2 ;;
    --router-dns) [ $# -ge 2 ] || usage; sans+=("DNS:$2"); shift 2 ;;
    --days) [ $# -ge 2 ] || usage; days="$2"; shift 2 ;;
    --actors) [ $# -ge 2 ] || usage; actors="$2"; shift 2 ;;
    --force) force=1; shift ;;
    -h|--help) usage ;;
    -*) echo "unknown option $1" >&2; usage ;;
    *) [ -z "$out" ] || usage; out="$1"; shift ;;
  esac
done
[ -n "$out" ] || usage
case "$actors" in
  ''|*[!0-9]*) echo "error: --actors needs a number, got '$actors'" >&2; exit 2 ;;
esac
[ "$actors" -ge 1 ] || { echo "error: --actors must be at least 1" >&2; exit 2; }
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
users=(learner evaluator monitor)
for ((i = 0; i < actors; i++)); do users+=("actor-$i"); done
: >"$tmp/router-users.txt"
for user in "${users[@]}"; do
  sign "$user" "$user" "$tmp/client.ext"
  pw="$(openssl rand -hex 24)"
  printf '%s\n' "$pw" >"$out/$user.password"
  printf '%s:%s\n' "$user" "$pw" >>"$tmp/router-users.txt"
done
mv "$tmp/router-users.txt" "$out/router-users.txt"
chmod 0755 "$out/certs"
chmod 0644 "$out"/certs/*.crt
chmod 0600 "$out"/certs/*.key "$out"/*.password "$out/router-users.txt"

openssl verify -CAfile "$out/certs/ca.crt" "$out/certs/router.crt" >/dev/null
echo "test CA, certificates and passwords written to $out (router SANs: $san_list; users: ${users[*]})"
