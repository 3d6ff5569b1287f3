/* hdr-bin and hdr-text frame encoders; see frame.h and docs/protocol.md. */
#include "frame.h"

uint16_t hdr_crc16_ccitt_false(const uint8_t *p, uint8_t n)
{
    uint16_t crc = 0xFFFF;
    while (n--) {
        crc ^= (uint16_t)((uint16_t)(*p++) << 8);
        for (uint8_t i = 0; i < 8; i++)
            crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ 0x1021) : (uint16_t)(crc << 1);
    }
    return crc;
}

static void put_le16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
}

uint8_t hdr_encode_bin(const hdr_sample_t *s, uint8_t *out)
{
    out[0] = HDR_SYNC0;
    out[1] = HDR_SYNC1;
    hdr_put_fields(s, out);
    put_le16(out + HDR_CRC_AT, hdr_crc16_ccitt_false(out + HDR_PAYLOAD_AT, HDR_PAYLOAD_LEN));
    return HDR_BIN_LEN;
}

/* Unsigned decimal, no leading zeros, at p; returns the position after it. */
static char *put_u32(char *p, uint32_t v)
{
    char digits[10];
    uint8_t n = 0;
    do {
        digits[n++] = (char)('0' + (uint8_t)(v % 10u));
        v /= 10u;
    } while (v);
    while (n)
        *p++ = digits[--n];
    return p;
}

static const char HEX[] = "0123456789ABCDEF";

uint8_t hdr_encode_text(const hdr_sample_t *s, char *out)
{
    static const char head[] = HDR_TEXT_SYNC;
    char *p = out;
    for (const char *h = head; *h; h++)
        *p++ = *h;
    p = put_u32(p, s->seq);
    *p++ = ',';
    p = put_u32(p, s->t_us);
    *p++ = ',';
    p = put_u32(p, s->rate);
    *p++ = ',';
    if (s->ref) /* 0 = no supply monitor: sent as an empty field */
        p = put_u32(p, s->ref);
    *p++ = ',';
    if (s->temp != HDR_TEMP_ABSENT) {
        int32_t t = s->temp;
        if (t < 0) {
            *p++ = '-';
            t = -t;
        }
        p = put_u32(p, (uint32_t)t / 100u);
        *p++ = '.';
        *p++ = (char)('0' + (uint8_t)((uint32_t)t / 10u % 10u));
        *p++ = (char)('0' + (uint8_t)((uint32_t)t % 10u));
    }
    uint8_t x = 0;
    for (const char *q = out + 1; q < p; q++) /* XOR of the bytes between '$' and '*' */
        x ^= (uint8_t)*q;
    *p++ = '*';
    *p++ = HEX[x >> 4];
    *p++ = HEX[x & 0x0F];
    *p++ = '\r';
    *p++ = '\n';
    return (uint8_t)(p - out);
}
