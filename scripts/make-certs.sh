#!/usr/bin/env bash
# Certificates for the bus link between the cart and a second machine (TLS):
#   scripts/make-certs.sh OUT_DIR HOSTNAME [IP]
# writes OUT_DIR/ca.pem + ca.key (the CA: keep ca.key off the machines), and OUT_DIR/router.pem +
# router.key, the cart router's certificate for HOSTNAME (and IP), signed by that CA. The cart
# gets router.pem, router.key and ca.pem; the second machine only ca.pem.
set -euo pipefail
out=${1:?usage: make-certs.sh OUT_DIR HOSTNAME [IP]}
host=${2:?usage: make-certs.sh OUT_DIR HOSTNAME [IP]}
ip=${3:-}
mkdir -p "$out"
san="DNS:${host}"
[ -n "$ip" ] && san="${san},IP:${ip}"
openssl req -x509 -newkey rsa:3072 -nodes -keyout "$out/ca.key" -out "$out/ca.pem" -days 3650 \
  -subj "/CN=tiplog bus CA" 2>/dev/null
openssl req -newkey rsa:3072 -nodes -keyout "$out/router.key" -out "$out/router.csr" \
  -subj "/CN=${host}" 2>/dev/null
openssl x509 -req -in "$out/router.csr" -CA "$out/ca.pem" -CAkey "$out/ca.key" -CAcreateserial \
  -out "$out/router.pem" -days 825 -extfile <(printf "subjectAltName=%s\n" "$san") 2>/dev/null
rm -f "$out/router.csr" "$out/ca.srl"
chmod 600 "$out/ca.key" "$out/router.key"
echo "$out: ca.pem (both machines), router.pem + router.key (the cart), ca.key (keep offline)"
