/* hdr-bin and hdr-text frame encoders (docs/protocol.md, "Wire protocol").
 *
 * Pure C99 with no AVR dependency, so the same file builds for the board and for the host
 * test that checks it against the protocol's worked examples.
 */
#ifndef HDRD_FRAME_H
#define HDRD_FRAME_H

#include <stdint.h>

#include "wire.h" /* the layout and hdr_sample_t, generated from hdrd's field table */

/* Longest hdr-text line this encoder writes, CR LF included:
 * "$HDRG," + 65535 + "," + 4294967295 + "," + 65535 + "," + 65535 + "," + -327.68 + "*HH\r\n"
 * = 6 + 5 + 1 + 10 + 1 + 5 + 1 + 5 + 1 + 7 + 5 = 47. */
#define HDR_TEXT_MAX 47u

/* CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor). */
uint16_t hdr_crc16_ccitt_false(const uint8_t *p, uint8_t n);

/* One hdr-bin frame into out (HDR_BIN_LEN bytes); returns HDR_BIN_LEN. */
uint8_t hdr_encode_bin(const hdr_sample_t *s, uint8_t *out);

/* One hdr-text line, CR LF included, into out (at least HDR_TEXT_MAX bytes); returns its
 * length. No terminating NUL. */
uint8_t hdr_encode_text(const hdr_sample_t *s, char *out);

#endif
