#!/usr/bin/env python3
"""Checks every local link and image of the built book.

Usage: check_site.py SITE [PAGES]

Reads every .html file under PAGES (default: SITE) and every href, src and
srcset in it. A reference that is a relative path (not http(s), mailto or
another scheme, not a pure #anchor) must name a file or folder that exists
inside SITE once its query and fragment are dropped. Prints each broken
reference with the page it is on, then the counts; exits 1 if any is broken.
Standard library only.
"""

import os
import sys
from html.parser import HTMLParser
from urllib.parse import unquote, urlsplit


class References(HTMLParser):
    """The (attribute, value) pairs of href, src and srcset in a page."""

    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.found = []

    def handle_starttag(self, tag, attrs):
        for name, value in attrs:
            if value is None:
                continue
            if name in ("href", "src"):
                self.found.append((tag, name, value.strip()))
            elif name == "srcset":
                for candidate in value.split(","):
                    url = candidate.strip().split(" ")[0]
                    if url:
                        self.found.append((tag, name, url))

    handle_startendtag = handle_starttag


def is_local(url):
    if not url or url.startswith("#"):
        return False
    parts = urlsplit(url)
    if parts.scheme or parts.netloc:  # http:, https:, mailto:, data:, javascript:, //host
        return False
    return bool(parts.path)


def main(argv):
    if len(argv) not in (2, 3):
        print(__doc__, file=sys.stderr)
        return 2
    site = os.path.realpath(argv[1])
    pages_root = os.path.realpath(argv[2]) if len(argv) == 3 else site
    pages = sorted(
        os.path.join(d, f)
        for d, _, files in os.walk(pages_root)
        for f in files
        if f.endswith(".html")
    )
    if not pages:
        print(f"no .html pages under {pages_root}", file=sys.stderr)
        return 1
    checked = 0
    images = 0
    broken = []
    for page in pages:
        parser = References()
        with open(page, encoding="utf-8") as f:
            parser.feed(f.read())
        for tag, attr, url in parser.found:
            if not is_local(url):
                continue
            path = unquote(urlsplit(url).path)
            if path.startswith("/"):
                target = os.path.join(site, path.lstrip("/"))
            else:
                target = os.path.join(os.path.dirname(page), path)
            target = os.path.realpath(target)
            checked += 1
            images += tag == "img"
            inside = target == site or target.startswith(site + os.sep)
            if not inside or not os.path.exists(target):
                why = "outside the site" if not inside else "missing"
                broken.append(f"{os.path.relpath(page, site)}: <{tag} {attr}=\"{url}\"> ({why})")
    for line in broken:
        print("broken:", line)
    broken_images = sum(1 for line in broken if line.split(": <", 1)[1].startswith("img "))
    print(
        f"{len(pages)} pages, {checked} local references checked ({images} of them images), "
        f"{len(broken)} broken ({broken_images} of them images)"
    )
    return 1 if broken else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
