// Query parameters as people type them: a "+" stays a "+" (replay ids contain it, e.g.
// astar+bayes), where URLSearchParams would read it as a space.
export function queryParam(name, search = location.search) {
  for (const part of search.replace(/^\?/, "").split("&")) {
    const [key, value = ""] = part.split("=");
    if (key && decodeURIComponent(key) === name) return decodeURIComponent(value);
  }
  return null;
}
