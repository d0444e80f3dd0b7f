#!/usr/bin/env bash
# Makes everything a TLS deployment behind one router needs, in OUT_DIR:
#   ca.pem, ca.key                      the certificate authority every process trusts
#   router.pem, router.key, router.json5 the router's certificate and Zenoh configuration
#   <name>.pem, <name>.key, <name>.json5 one client certificate (common name <name>) and
#                                        Zenoh configuration per name given
# Usage: make-certs.sh OUT_DIR NAME... (e.g. engine-1 trainer-1 alice)
# ROUTER_ENDPOINT (default quic/localhost:7447) is where the others connect (the router
# listens on ROUTER_LISTEN, default the same port on every interface), and its host must
# be one the router's certificate names (localhost, 127.0.0.1 or ROUTER_HOST). QUIC is
# TLS 1.3 over UDP; Zenoh 1.10's tls/ (TLS over TCP) link drops requests under sustained
# traffic (deploy/secure/README.md), so quic/ is the default. Certificates are valid for
# DAYS (default 365) days. Needs openssl.
set -euo pipefail

if [ $# -lt 2 ]; then
    echo "usage: $0 OUT_DIR NAME..." >&2
    exit 2
fi
out=$1
shift
endpoint=${ROUTER_ENDPOINT:-quic/localhost:7447}
router_host=${ROUTER_HOST:-localhost}
days=${DAYS:-365}
command -v openssl >/dev/null || { echo "$0: openssl is needed" >&2; exit 1; }
mkdir -p "$out"
out=$(cd "$out" && pwd)

for name in "$@"; do
    if ! [[ $name =~ ^[A-Za-z0-9._-]+$ ]] || [ "$name" = router ] || [ "$name" = ca ]; then
        echo "$0: name '$name' must be letters, digits, '.', '_' or '-' (and not router or ca)" >&2
        exit 2
    fi
done

# A P-256 key (PKCS#8) and a certificate for CN=$1 signed by the CA, with extensions from $2.
issue() {
    local name=$1 extensions=$2
    openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$out/$name.key" 2>/dev/null
    openssl req -new -key "$out/$name.key" -subj "/CN=$name" -out "$out/$name.csr"
    openssl x509 -req -in "$out/$name.csr" -CA "$out/ca.pem" -CAkey "$out/ca.key" \
        -CAcreateserial -days "$days" -sha256 -extfile <(printf '%s\n' "$extensions") \
        -out "$out/$name.pem" 2>/dev/null
    rm -f "$out/$name.csr"
    chmod 600 "$out/$name.key"
}

if [ ! -f "$out/ca.pem" ]; then
    openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$out/ca.key" 2>/dev/null
    openssl req -x509 -new -key "$out/ca.key" -subj "/CN=ciflow deployment CA" -days "$days" \
        -sha256 -addext "basicConstraints=critical,CA:TRUE" \
        -addext "keyUsage=critical,keyCertSign,cRLSign" -out "$out/ca.pem"
    chmod 600 "$out/ca.key"
fi

leaf="basicConstraints=critical,CA:FALSE
keyUsage=critical,digitalSignature"
issue router "$leaf
extendedKeyUsage=serverAuth
subjectAltName=DNS:localhost,IP:127.0.0.1,DNS:$router_host"
cat >"$out/router.json5" <<JSON
{
  // ciflow router --config router.json5 --engine E --trainer T --client C ...
  mode: "router",
  listen: { endpoints: ["${ROUTER_LISTEN:-${endpoint/localhost/0.0.0.0}}"] },
  scouting: { multicast: { enabled: false } },
  transport: {
    link: {
      tx: { lease: 3000 },
      tls: {
        root_ca_certificate: "$out/ca.pem",
        listen_certificate: "$out/router.pem",
        listen_private_key: "$out/router.key",
        // Every peer shows a certificate of this CA; its common name is its identity.
        enable_mtls: true,
      },
    },
  },
}
JSON

for name in "$@"; do
    issue "$name" "$leaf
extendedKeyUsage=clientAuth
subjectAltName=DNS:$name"
    cat >"$out/$name.json5" <<JSON
{
  // The Zenoh configuration of '$name': a client of the router, known by its certificate.
  mode: "client",
  connect: { endpoints: ["$endpoint"] },
  scouting: { multicast: { enabled: false } },
  transport: {
    link: {
      tx: { lease: 3000 },
      tls: {
        root_ca_certificate: "$out/ca.pem",
        connect_certificate: "$out/$name.pem",
        connect_private_key: "$out/$name.key",
        // Show the certificate to the router: it is how the router knows who this is.
        enable_mtls: true,
      },
    },
  },
}
JSON
done
echo "certificates and Zenoh configurations in $out"
