/* Listens for handover events over UDP and prints one line per event (docs/EVENTS.md).
 *
 * Build: gcc -std=c99 -O2 -Wall -o udp_listener udp_listener.c
 * Run:   ./udp_listener 5005            (daemon config: [sinks] udp = ["127.0.0.1:5005"])
 *        ./udp_listener 0 3             (any free port, printed first; exit after 3 events)
 *
 * Each datagram is one JSON object. This example reads only the flat top-level fields it
 * prints, with strstr; use a JSON library (cJSON, jansson) for the scores or anything more.
 * Lines whose "type" it does not know are skipped, as the protocol asks.
 */
#define _POSIX_C_SOURCE 200112L
#include <arpa/inet.h>
#include <netinet/in.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

/* Copies the value of top-level field "key" (string without quotes, or a bare number /
 * true / false / null) into out. Returns 1 when found. */
static int field(const char *line, const char *key, char *out, size_t size) {
    char pattern[64];
    snprintf(pattern, sizeof pattern, "\"%s\":", key);
    const char *p = strstr(line, pattern);
    if (!p || size == 0) return 0;
    p += strlen(pattern);
    size_t n = 0;
    if (*p == '"') {
        for (p++; *p && *p != '"' && n + 1 < size; p++) out[n++] = *p;
    } else {
        for (; *p && *p != ',' && *p != '}' && n + 1 < size; p++) out[n++] = *p;
    }
    out[n] = '\0';
    return 1;
}

int main(int argc, char **argv) {
    int port = argc > 1 ? atoi(argv[1]) : 5005;
    long count = argc > 2 ? atol(argv[2]) : -1; /* -1: forever */
    int sock = socket(AF_INET, SOCK_DGRAM, 0);
    if (sock < 0) { perror("socket"); return 1; }
    struct sockaddr_in addr;
    memset(&addr, 0, sizeof addr);
    addr.sin_family = AF_INET;
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    addr.sin_port = htons((unsigned short)port);
    if (bind(sock, (struct sockaddr *)&addr, sizeof addr) < 0) { perror("bind"); return 1; }
    socklen_t len = sizeof addr;
    getsockname(sock, (struct sockaddr *)&addr, &len);
    printf("listening on udp 127.0.0.1:%d\n", ntohs(addr.sin_port));
    fflush(stdout);

    char buf[65536], type[32], protocol[16], a[64], b[64], c[64], d[64];
    for (long seen = 0; count < 0 || seen < count;) {
        ssize_t n = recv(sock, buf, sizeof buf - 1, 0);
        if (n <= 0) continue;
        buf[n] = '\0';
        if (!field(buf, "type", type, sizeof type) || !field(buf, "protocol", protocol, sizeof protocol)) {
            fprintf(stderr, "not an event line, skipped\n");
            continue;
        }
        if (atoi(protocol) != 1) fprintf(stderr, "protocol %s is newer than this listener (1)\n", protocol);
        if (strcmp(type, "decision") == 0) {
            field(buf, "class", a, sizeof a);
            field(buf, "latency_us", b, sizeof b);
            field(buf, "model_id", c, sizeof c);
            field(buf, "frame_last", d, sizeof d);
            printf("decision %s latency_us=%s model=%s frame_last=%s\n", a, b, c, d);
        } else if (strcmp(type, "model") == 0) {
            field(buf, "model_id", a, sizeof a);
            field(buf, "model_version", b, sizeof b);
            field(buf, "previous_model_id", c, sizeof c);
            printf("model %s version=%s previous=%s\n", a, b, c);
        } else {
            continue; /* a line type this listener does not know */
        }
        fflush(stdout);
        seen++;
    }
    close(sock);
    return 0;
}
